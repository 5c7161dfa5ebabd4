"""SQLAlchemy declarative base, engine and session factory.

Every model in the project derives from :class:`Base`; :func:`make_engine` creates the
SQLite database (with WAL, so the API and background tasks can read while one writes) and
the tables that do not exist yet. Schema changes of later releases go through alembic.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from sqlalchemy import Engine, create_engine, event
from sqlalchemy.orm import DeclarativeBase, sessionmaker


class Base(DeclarativeBase):
    """Declarative base of every gaitrig table."""


def make_engine(location: Path | str) -> Engine:
    """Open (and create if needed) the database.

    Args:
        location: a SQLAlchemy URL (``sqlite:///...``, ``postgresql+psycopg://...``) or
            the path of a SQLite file.
    """
    url = str(location)
    if "://" not in url:
        Path(url).parent.mkdir(parents=True, exist_ok=True)
        url = f"sqlite:///{url}"
    if url.startswith("sqlite"):
        engine = create_engine(url, connect_args={"check_same_thread": False})

        @event.listens_for(engine, "connect")
        def _pragmas(conn: Any, _record: Any) -> None:
            cur = conn.cursor()
            cur.execute("PRAGMA journal_mode=WAL")
            cur.execute("PRAGMA foreign_keys=ON")
            cur.close()
    else:
        engine = create_engine(url, pool_pre_ping=True)

    import app.db.models  # noqa: F401  (register the tables)
    from app.db.data import DATA_TABLES, upgrade_database

    # The data tables are versioned by alembic (app.db.data); the rest is created here.
    Base.metadata.create_all(engine, tables=[t for n, t in Base.metadata.tables.items()
                                             if n not in DATA_TABLES])
    upgrade_database(engine)
    return engine


def make_session_factory(engine: Engine) -> sessionmaker[Any]:
    """Session factory bound to ``engine`` (sessions don't expire objects on commit)."""
    return sessionmaker(engine, expire_on_commit=False)
