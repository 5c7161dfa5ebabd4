"""Data-management tables: projects → subjects → sessions → recordings → node parts.

A :class:`Recording` row shares its id with the backbone's in-memory
:class:`app.server.recording.Recording` (``R20260101-120000-ab12``); the backbone keeps the
live part states of the nodes, this table adds where the recording belongs (a session of a
subject of a project) and the server-side transfer state of every node part.

Recording states (:data:`RECORDING_STATES`): ``recording`` → ``on_nodes`` (every part
closed on its node) → ``transferring`` → ``complete`` (every part verified on the server)
or ``incomplete`` (with ``reason``: which node and why). Part states
(:data:`PART_STATES`) add ``pending`` (command sent) and ``on_node``.

Units are SI (height and leg length in metres); the console converts to cm.

The schema is versioned by alembic (``alembic/versions``); :func:`upgrade_database` brings
any database, new or created by an older release, to the newest revision and is called
when the server opens its database.
"""

from __future__ import annotations

import json
import logging
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from sqlalchemy import (
    BigInteger,
    Date,
    DateTime,
    Engine,
    Float,
    ForeignKey,
    Integer,
    String,
    Text,
    UniqueConstraint,
)
from sqlalchemy.orm import Mapped, mapped_column, relationship

from app.db.base import Base

RECORDING_STATES = ("recording", "on_nodes", "transferring", "complete", "incomplete")
PART_STATES = ("pending", "recording", "on_node", "transferring", "complete", "incomplete")
SEXES = ("female", "male", "other", "unknown")
REFERENCE_FORMATS = ("c3d", "trc", "csv")

ALEMBIC_DIR = Path(__file__).resolve().parents[2] / "alembic"


def _now() -> datetime:
    return datetime.now(UTC)


class Project(Base):
    """A study or clinic: groups subjects (codes are unique within a project)."""

    __tablename__ = "projects"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(String(120), unique=True)
    description: Mapped[str] = mapped_column(Text, default="")
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=_now)

    subjects: Mapped[list[Subject]] = relationship(
        back_populates="project", cascade="all, delete-orphan", order_by="Subject.code")


class Subject(Base):
    """A pseudonymised person: no names, only a code chosen by the clinic."""

    __tablename__ = "subjects"
    __table_args__ = (UniqueConstraint("project_id", "code", name="uq_subject_code"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    project_id: Mapped[int] = mapped_column(ForeignKey("projects.id", ondelete="CASCADE"),
                                            index=True)
    code: Mapped[str] = mapped_column(String(40), index=True)
    height_m: Mapped[float | None] = mapped_column(Float, nullable=True)
    leg_length_m: Mapped[float | None] = mapped_column(Float, nullable=True)
    sex: Mapped[str] = mapped_column(String(10), default="unknown")
    birth_year: Mapped[int | None] = mapped_column(Integer, nullable=True)
    notes: Mapped[str] = mapped_column(Text, default="")
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=_now)

    project: Mapped[Project] = relationship(back_populates="subjects")
    sessions: Mapped[list[Session]] = relationship(
        back_populates="subject", cascade="all, delete-orphan", order_by="Session.date")


class Session(Base):
    """One visit of a subject (a date and a label such as "baseline")."""

    __tablename__ = "sessions"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    subject_id: Mapped[int] = mapped_column(ForeignKey("subjects.id", ondelete="CASCADE"),
                                            index=True)
    date: Mapped[Any] = mapped_column(Date)
    label: Mapped[str] = mapped_column(String(120), default="")
    notes: Mapped[str] = mapped_column(Text, default="")
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=_now)

    subject: Mapped[Subject] = relationship(back_populates="sessions")
    recordings: Mapped[list[Recording]] = relationship(
        back_populates="session", cascade="all, delete-orphan", order_by="Recording.created_at")


class Recording(Base):
    """A synchronous recording of a session (id = the backbone's recording id)."""

    __tablename__ = "recordings"

    id: Mapped[str] = mapped_column(String(64), primary_key=True)
    session_id: Mapped[int] = mapped_column(ForeignKey("sessions.id", ondelete="CASCADE"),
                                            index=True)
    label: Mapped[str] = mapped_column(String(120), default="")
    notes: Mapped[str] = mapped_column(Text, default="")
    state: Mapped[str] = mapped_column(String(16), default="recording", index=True)
    reason: Mapped[str | None] = mapped_column(Text, nullable=True)
    t_start: Mapped[float | None] = mapped_column(Float, nullable=True)  # server epoch s
    t_stop: Mapped[float | None] = mapped_column(Float, nullable=True)
    streams: Mapped[str] = mapped_column(String(120), default="")  # comma separated
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=_now,
                                                 index=True)

    session: Mapped[Session] = relationship(back_populates="recordings")
    parts: Mapped[list[RecordingPart]] = relationship(
        back_populates="recording", cascade="all, delete-orphan",
        order_by="RecordingPart.node_id")
    references: Mapped[list[ReferenceImport]] = relationship(
        back_populates="recording", cascade="all, delete-orphan",
        order_by="ReferenceImport.created_at")

    @property
    def duration_s(self) -> float | None:
        """Recorded duration, once stopped."""
        if self.t_start is None or self.t_stop is None:
            return None
        return max(0.0, self.t_stop - self.t_start)


class RecordingPart(Base):
    """One node's share of a recording and its transfer to the server."""

    __tablename__ = "recording_parts"
    __table_args__ = (UniqueConstraint("recording_id", "node_id", name="uq_part_node"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    recording_id: Mapped[str] = mapped_column(
        ForeignKey("recordings.id", ondelete="CASCADE"), index=True)
    node_id: Mapped[str] = mapped_column(String(64))
    state: Mapped[str] = mapped_column(String(16), default="pending")
    reason: Mapped[str | None] = mapped_column(Text, nullable=True)
    n_frames: Mapped[int] = mapped_column(Integer, default=0)
    bytes_total: Mapped[int] = mapped_column(BigInteger, default=0)
    bytes_done: Mapped[int] = mapped_column(BigInteger, default=0)
    manifest_sha256: Mapped[str | None] = mapped_column(String(64), nullable=True)
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    # frames recorded without their images (the node's encoder fell behind), from the
    # server copy's meta.json when the part arrived; None before (or before revision 0002)
    images_skipped: Mapped[int | None] = mapped_column(Integer, nullable=True)
    updated_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=_now,
                                                 onupdate=_now)

    recording: Mapped[Recording] = relationship(back_populates="parts")

    @property
    def progress(self) -> float:
        """Transferred fraction 0..1 (1 once complete)."""
        if self.state == "complete":
            return 1.0
        return self.bytes_done / self.bytes_total if self.bytes_total else 0.0


class ReferenceImport(Base):
    """A reference recording (e.g. Vicon C3D) attached to a recording for agreement."""

    __tablename__ = "reference_imports"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    recording_id: Mapped[str] = mapped_column(
        ForeignKey("recordings.id", ondelete="CASCADE"), index=True)
    filename: Mapped[str] = mapped_column(String(255))  # as uploaded (display only)
    format: Mapped[str] = mapped_column(String(8))
    stored_name: Mapped[str] = mapped_column(String(80))  # file name in the folder
    size: Mapped[int] = mapped_column(BigInteger, default=0)
    rate_hz: Mapped[float] = mapped_column(Float, default=0.0)
    n_frames: Mapped[int] = mapped_column(Integer, default=0)
    labels_json: Mapped[str] = mapped_column(Text, default="[]")
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=_now)

    recording: Mapped[Recording] = relationship(back_populates="references")

    @property
    def labels(self) -> list[str]:
        """Marker / joint labels of the reference."""
        out: list[str] = json.loads(self.labels_json or "[]")
        return out


DATA_TABLES = ("projects", "subjects", "sessions", "recordings", "recording_parts",
               "reference_imports")


def upgrade_database(engine: Engine) -> None:
    """Bring the data tables of ``engine``'s database to the newest alembic revision.

    Works for a new database and for one created by an older release (the first
    revision only creates the tables that are missing, so a database whose tables were
    made by ``create_all`` is adopted, not broken).
    """
    from alembic.config import Config

    from alembic import command

    # alembic announces every plugin at INFO; only the migrations themselves matter
    logging.getLogger("alembic.runtime.plugins").setLevel(logging.WARNING)
    cfg = Config()
    cfg.set_main_option("script_location", str(ALEMBIC_DIR))
    # configparser would read "%" (percent-encoded passwords, socket paths) as interpolation
    cfg.set_main_option("sqlalchemy.url",
                        engine.url.render_as_string(hide_password=False).replace("%", "%%"))
    with engine.begin() as conn:
        cfg.attributes["connection"] = conn
        command.upgrade(cfg, "head")
