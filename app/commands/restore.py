"""``gaitrig restore ARCHIVE --data-dir DIR``: restore a backup into an empty data folder.

The archive is checked while it is unpacked, the database is brought to this gaitrig's
alembic head, and every deletion of the current erasure log (``--deletion-log``) is
applied again, so that restoring a backup made before a subject was deleted does not
bring the subject back. Stop the server first. See ``docs/backup.md``. Errors: one line
on stderr, exit code 2; nothing is changed then.
"""

from __future__ import annotations

import argparse
import socket
from pathlib import Path

from engine.wording import count

HELP = "restore a backup into an empty data folder (deletions made since are applied again)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the command's options."""
    parser.add_argument("archive", metavar="ARCHIVE", type=Path,
                        help="the .tar written by gaitrig backup")
    parser.add_argument("--data-dir", type=Path, required=True,
                        help="data folder to restore into (empty or missing)")
    parser.add_argument("--deletion-log", type=Path, action="append", default=[],
                        metavar="PATH",
                        help="the current erasure log: the old server's data folder or its "
                             "erasures.jsonl, or a newer backup (repeatable); required "
                             "unless --without-deletion-log")
    parser.add_argument("--without-deletion-log", action="store_true",
                        help="restore without a current erasure log (only when nothing was "
                             "deleted since the backup, or the log is lost: recorded in the "
                             "audit trail)")
    parser.add_argument("--force", action="store_true",
                        help="replace everything in a non-empty --data-dir (its erasure log "
                             "is applied first)")


def run(args: argparse.Namespace) -> int:
    """Restore. Returns the exit code."""
    from app.commands.backup import actor, fail
    from app.config import Settings
    from app.server.backup import BackupError, restore_backup

    try:
        res = restore_backup(args.archive, args.data_dir, list(args.deletion_log),
                             without_deletion_log=args.without_deletion_log,
                             force=args.force, db_url=Settings().database_url,
                             actor=actor(), client=socket.gethostname())
    except (BackupError, OSError) as exc:
        return fail("restore", exc, args.data_dir)
    man = res.manifest
    print(f"gaitrig restore: {res.data_dir}: backup of {man['created_at']} (gaitrig "
          f"{man['gaitrig_version']}), database revision {res.revision_before} -> "
          f"{res.revision_after}")
    if args.without_deletion_log and not args.deletion_log:
        print("  WARNING: restored without the current erasure log: subjects deleted after "
              "this backup are back unless you delete them again")
    print(f"  {count(len(res.erased_recordings), 'deleted recording')} kept deleted, "
          f"{count(res.erased_references, 'deleted reference')} deleted again "
          f"({count(res.erasures_applied, 'deletion')} of the erasure logs applied)")
    for n in res.notes:
        print(f"  NOTE: {n}")
    print(f"  start the server with --data-dir {res.data_dir} (or GAITRIG_DATA_DIR)")
    return 0
