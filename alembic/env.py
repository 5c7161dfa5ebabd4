"""Alembic environment of the gaitrig data and account tables.

Called by :func:`app.db.data.upgrade_database` with an open connection (in
``config.attributes["connection"]``), or from the command line with the URL of
``GAITRIG_DATABASE_URL`` / ``alembic.ini``.
"""

from __future__ import annotations

import os

from sqlalchemy import create_engine

from alembic import context
from app.db import data, models  # (importing them registers every table)
from app.db.base import Base

config = context.config
target_metadata = Base.metadata


def _include(obj: object, name: str | None, type_: str, *_: object) -> bool:
    # The data and account tables are versioned here; the audit trail is made by create_all.
    if type_ == "table":
        return name in data.DATA_TABLES or name in models.ACCOUNT_TABLES
    return True


def run() -> None:
    """Run the migrations on the given connection or URL."""
    conn = config.attributes.get("connection")
    if conn is not None:
        context.configure(connection=conn, target_metadata=target_metadata,
                          include_object=_include, render_as_batch=True)
        with context.begin_transaction():
            context.run_migrations()
        return
    url = os.environ.get("GAITRIG_DATABASE_URL") or config.get_main_option("sqlalchemy.url")
    engine = create_engine(str(url))
    with engine.begin() as c:
        context.configure(connection=c, target_metadata=target_metadata,
                          include_object=_include, render_as_batch=True)
        with context.begin_transaction():
            context.run_migrations()


run()
