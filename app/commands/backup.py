"""``gaitrig backup DEST``: a consistent backup of a running server; ``--verify ARCHIVE``.

The database is copied with SQLite's online backup API (not a file copy of a database
in WAL mode), the data folder's files are streamed into one ``.tar`` with the SHA-256 of
each, parts still being transferred are left out and named. The backup is recorded in
the audit trail (the console shows its time). See ``docs/backup.md``. Errors: one line on
stderr, exit code 2; a verification that finds damage: exit code 1.
"""

from __future__ import annotations

import argparse
import getpass
import socket
import sys
from pathlib import Path
from typing import Any

from engine.wording import count

HELP = "back up the server's database and data folder into one archive (or --verify one)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the command's options."""
    parser.add_argument("dest", metavar="DEST", type=Path,
                        help="archive to write (.tar), or a folder to write "
                             "gaitrig-backup-<UTC time>.tar into; with --verify: the "
                             "archive to check")
    parser.add_argument("--verify", action="store_true",
                        help="check every checksum and the database's integrity of the "
                             "archive DEST, restoring nothing")
    parser.add_argument("--data-dir", type=Path,
                        help="server data folder (default GAITRIG_DATA_DIR or ./var)")


def actor() -> str:
    """Who runs the command, for the audit trail."""
    try:
        who = getpass.getuser()
    except (KeyError, OSError):
        who = "unknown"
    return f"{who} (command line)"


def record(db_url: str, action: str, target: str, detail: str) -> str | None:
    """Append an audit entry to the server's database; the error's text if it fails."""
    from sqlalchemy import create_engine
    from sqlalchemy.exc import SQLAlchemyError
    from sqlalchemy.orm import Session

    from app.db import audit

    engine = create_engine(db_url, connect_args={"timeout": 30}
                           if db_url.startswith("sqlite") else {})
    try:
        with Session(engine) as db:
            audit.record(db, actor(), action, target, detail, socket.gethostname())
    except SQLAlchemyError as exc:
        return str(exc).splitlines()[0]
    finally:
        engine.dispose()
    return None


def fail(command: str, exc: Exception, path: Path) -> int:
    """Print the one-line error of ``gaitrig backup``/``restore`` on stderr.

    Args:
        command: ``backup`` or ``restore``.
        exc: a :class:`app.server.backup.BackupError` (its text says what to do) or an
            ``OSError`` (named by its file, ``path`` when it names none).
        path: what the command was working on.

    Returns:
        The exit code of an error, 2.
    """
    if isinstance(exc, OSError):
        text = f"{exc.filename or path}: {exc.strerror or exc}"
    else:
        text = str(exc)
    print(f"gaitrig {command}: error: {text}", file=sys.stderr)
    return 2


def run(args: argparse.Namespace) -> int:
    """Back up, or verify an archive. Returns the exit code."""
    from app.config import Settings
    from app.server.backup import BackupError, create_backup, verify_backup

    if args.verify:
        try:
            v = verify_backup(args.dest)
        except (BackupError, OSError) as exc:
            return fail("backup", exc, args.dest)
        man = v.manifest
        print(f"gaitrig backup: {args.dest}: made {man['created_at']} by gaitrig "
              f"{man['gaitrig_version']}, database revision {man['alembic_revision']}, "
              f"{v.checked} members checked")
        for p in v.problems:
            print(f"  DAMAGED: {p}", file=sys.stderr)
        if v.problems:
            print(f"gaitrig backup: {args.dest} is damaged ({count(len(v.problems), 'problem')}); "
                  "do not rely on it", file=sys.stderr)
            return 1
        print("gaitrig backup: every checksum matches and the database passes "
              "PRAGMA integrity_check" if man["database"].get("member") else
              "gaitrig backup: every checksum matches (no database in it: PostgreSQL)")
        return 0

    over: dict[str, Any] = {"data_dir": args.data_dir} if args.data_dir else {}
    settings = Settings(**over)
    try:
        res = create_backup(settings.data_dir, args.dest, settings.db_url)
    except (BackupError, OSError) as exc:
        return fail("backup", exc, args.dest)
    man = res.manifest
    c = man["counts"]
    print(f"gaitrig backup: {res.path}: {c.get('subjects', '?')} subjects, "
          f"{c.get('recordings', '?')} recordings, {c['files']} files "
          f"({c['file_bytes'] / 1e6:.1f} MB), database revision {man['alembic_revision']}")
    for s in res.skipped:
        print(f"  left out: {s['path']}: {s['why']}")
    for n in man["notes"]:
        print(f"  NOTE: {n}")
    err = record(settings.db_url, "backup", res.path.name,
                 f"{c['files']} files, {len(res.skipped)} left out")
    if err is not None:
        print(f"gaitrig backup: the backup is complete but could not be recorded in the "
              f"audit trail ({err}); the console will not show it", file=sys.stderr)
        return 1
    return 0
