"""Fixtures of the data-management tests: real server and node processes (see
:mod:`tests.integration.conftest`), and a throw-away PostgreSQL server (``pg_server``,
``pg_url``: skipped, with the reason, when PostgreSQL or psycopg is not installed)."""

from __future__ import annotations

import glob
import itertools
import os
import pwd
import shutil
import subprocess
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest
import sqlalchemy as sa

from tests.integration.conftest import make_rig  # noqa: F401  (fixture)

_dbs = itertools.count(1)


def pg_tool(name: str) -> str | None:
    """The path of a PostgreSQL program (PATH, else the newest /usr/lib/postgresql)."""
    found = shutil.which(name)
    if found:
        return found
    versions = sorted(glob.glob(f"/usr/lib/postgresql/*/bin/{name}"))
    return versions[-1] if versions else None


@pytest.fixture(scope="module")
def pg_server() -> Iterator[str]:
    """Base URL (without database) of a throw-away PostgreSQL server."""
    initdb, pg_ctl = pg_tool("initdb"), pg_tool("pg_ctl")
    if initdb is None or pg_ctl is None:
        pytest.skip("PostgreSQL is not installed (no initdb/pg_ctl; apt-get install postgresql)")
    pytest.importorskip("psycopg", reason="the psycopg driver is not installed "
                                          "(pip install 'psycopg[binary]')")
    prefix: list[str] = []
    root = Path(tempfile.mkdtemp(prefix="gaitrig-pg-"))
    if os.geteuid() == 0:  # PostgreSQL refuses to run as root
        try:
            user = pwd.getpwnam("postgres")
        except KeyError:
            shutil.rmtree(root)
            pytest.skip("running as root and there is no 'postgres' user to run PostgreSQL")
        os.chown(root, user.pw_uid, user.pw_gid)
        prefix = ["runuser", "-u", "postgres", "--"]
    data, sock = root / "data", root / "sock"

    def run(*cmd: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([*prefix, *cmd], capture_output=True, text=True, timeout=120)

    r = run("mkdir", str(sock))
    r = run(initdb, "-D", str(data), "-U", "gaitrig", "-A", "trust", "-E", "UTF8", "--no-sync")
    if r.returncode != 0:
        shutil.rmtree(root, ignore_errors=True)
        pytest.skip(f"initdb failed: {r.stderr.strip()[-300:]}")
    r = run(pg_ctl, "-D", str(data), "-l", str(root / "log"), "-w", "-o",
            f"-k {sock} -c listen_addresses='' -p 5432 -F", "start")
    if r.returncode != 0:
        log = (root / "log").read_text(errors="replace") if (root / "log").exists() else ""
        shutil.rmtree(root, ignore_errors=True)
        pytest.skip(f"PostgreSQL did not start: {(r.stderr + log).strip()[-300:]}")
    try:
        yield f"postgresql+psycopg://gaitrig@/{{db}}?host={sock}&port=5432"
    finally:
        run(pg_ctl, "-D", str(data), "-m", "immediate", "stop")
        shutil.rmtree(root, ignore_errors=True)


@pytest.fixture
def pg_url(pg_server: str) -> str:
    """A fresh, empty database on the server."""
    name = f"gaitrig_test_{next(_dbs)}"
    admin = sa.create_engine(pg_server.format(db="postgres"), isolation_level="AUTOCOMMIT")
    with admin.connect() as c:
        c.execute(sa.text(f"create database {name}"))
    admin.dispose()
    return pg_server.format(db=name)
