"""SQLAlchemy declarative base, engine and session factory.

Every model in the project derives from :class:`Base`; :func:`make_engine` creates the
SQLite database (with WAL, so the API and background tasks can read while one writes) and
brings its tables up to date: the data and account tables through alembic, the audit
trail by ``create_all``.
"""

from __future__ import annotations

import time
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
            # health data: a deleted row is overwritten with zeros, not left in free space
            cur.execute("PRAGMA secure_delete=ON")
            cur.close()
    else:
        engine = create_engine(url, pool_pre_ping=True)

    from app.db.data import DATA_TABLES, upgrade_database
    from app.db.models import ACCOUNT_TABLES

    # The data and account tables are versioned by alembic (app.db.data, revision 0005);
    # the audit trail (its append-only triggers come with create_all) is created here.
    versioned = set(DATA_TABLES) | set(ACCOUNT_TABLES)
    Base.metadata.create_all(engine, tables=[t for n, t in Base.metadata.tables.items()
                                             if n not in versioned])
    upgrade_database(engine)
    return engine


def alembic_head() -> str:
    """The newest alembic revision of this release (what :func:`make_engine` upgrades to).

    Raises:
        RuntimeError: the revisions do not form one line (two heads: a revision chained
            onto an older one than the newest).
    """
    from alembic.config import Config
    from alembic.script import ScriptDirectory

    from app.db.data import ALEMBIC_DIR

    cfg = Config()
    cfg.set_main_option("script_location", str(ALEMBIC_DIR))
    heads = ScriptDirectory.from_config(cfg).get_heads()
    if len(heads) != 1:
        raise RuntimeError(f"alembic/versions has {len(heads)} heads ({', '.join(heads)}); "
                           "chain the newest revision onto the one before it")
    return str(heads[0])


def purge_deleted(engine: Engine, attempts: int = 10, wait_s: float = 0.3) -> bool:
    """Make deleted rows unrecoverable from the database files, after a deletion commits.

    With ``secure_delete`` SQLite zeroes deleted content in the pages it writes, but the
    write-ahead log still holds earlier versions of those pages (the inserts and updates
    of the deleted rows) until it is checkpointed and truncated. Other databases keep dead
    rows until their own vacuum; nothing is done for them here.

    A checkpoint that waits for readers holds off every writer meanwhile (the data sync
    writes from the event loop), so each try waits at most 0.2 s; between tries nothing
    is held.

    Returns:
        True when the log was emptied (or the database is not SQLite); False when readers
        kept it busy for every try (the next deletion or edit catches up).
    """
    if engine.dialect.name != "sqlite":
        return True
    for k in range(attempts):
        if k:
            time.sleep(wait_s)
        with engine.connect() as conn:
            before = conn.exec_driver_sql("PRAGMA busy_timeout").scalar()
            conn.exec_driver_sql("PRAGMA busy_timeout=200")
            try:
                row = conn.exec_driver_sql("PRAGMA wal_checkpoint(TRUNCATE)").fetchone()
            finally:
                conn.exec_driver_sql(f"PRAGMA busy_timeout={int(before or 0)}")
        if row is not None and row[0] == 0:
            return True
    return False


def make_session_factory(engine: Engine) -> sessionmaker[Any]:
    """Session factory bound to ``engine`` (sessions don't expire objects on commit)."""
    return sessionmaker(engine, expire_on_commit=False)
