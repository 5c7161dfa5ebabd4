"""Backup, verification and restore of a server's data folder and database.

An archive is one uncompressed tar file (the recordings are compressed already; an
uncompressed tar can be read member by member without unpacking it)::

    database/gaitrig.sqlite3     the SQLite database, taken with SQLite's online backup
                                 API (a consistent snapshot while the server writes)
    files/<path>                 every file of the data folder, except the database and
                                 parts still being transferred
    files/erasures.jsonl         the erasure log, copied last (app.server.erasures)
    gaitrig-backup.json          the manifest, last: gaitrig version, alembic revision,
                                 counts, created time, size and SHA-256 of every member,
                                 what was left out and why

The database is copied first and the files after it, so a recording that completes
meanwhile is at worst a file the database does not know yet, never a row without its
files; a recording deleted meanwhile is in the erasure log copied last, which the
restore applies. Files are streamed (1 MiB at a time) and hashed as they are written:
memory stays bounded whatever the size of the data folder.

With PostgreSQL the archive holds the files only; the operator backs the database up
with ``pg_dump`` just before (database first, files after, as above) and restores it with
``pg_restore`` before ``gaitrig restore`` (the manifest and the command's output say so).
The manifest then records the database's alembic revision and row counts as read when
the files were copied, and the restore refuses a database that was not restored yet
(empty) or that a running server still uses.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import shutil
import sqlite3
import tarfile
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path, PurePosixPath
from typing import IO, Any, BinaryIO

from sqlalchemy import desc, select
from sqlalchemy.engine import make_url

from app.server import erasures
from engine.errors import InputError

FORMAT = "gaitrig-backup/1"
MANIFEST = "gaitrig-backup.json"
DB_MEMBER = "database/gaitrig.sqlite3"
FILES = "files/"
ERASURE_MEMBER = FILES + erasures.LOG_NAME
_BUF = 1 << 20
_COUNTED = ("projects", "subjects", "sessions", "recordings", "recording_parts",
            "reference_imports", "users", "audit_events")
#: Files of the data folder that are never copied: the database (snapshotted instead)
#: and its journals, and the temporary files of atomic writes.
_DB_FILES = ("gaitrig.sqlite3", "gaitrig.sqlite3-wal", "gaitrig.sqlite3-shm",
             "gaitrig.sqlite3-journal")

PG_HOW = ("the database is PostgreSQL: this archive holds the files only. Back up the "
          "database just before each backup with pg_dump (pg_dump -Fc -f gaitrig.pgdump "
          "\"$GAITRIG_DATABASE_URL\" with the driver part '+psycopg' removed) and keep "
          "both together; restore it with pg_restore into an empty database before "
          "running gaitrig restore (docs/backup.md)")
#: What to install when the PostgreSQL client programs are missing.
PG_CLIENT = ("the PostgreSQL client programs pg_dump and pg_restore (apt-get install "
             "postgresql-client, of the server's major version or newer)")


class BackupError(InputError):
    """A backup cannot be made, verified or restored; the message says what to do."""


def gaitrig_version() -> str:
    """The installed gaitrig version (``dev`` when run from a bare checkout)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("gaitrig")
    except PackageNotFoundError:
        return "dev"


def sqlite_path(db_url: str) -> Path | None:
    """The file of a SQLite database URL (None for any other database)."""
    url = make_url(db_url)
    if url.get_backend_name() != "sqlite":
        return None
    if not url.database or url.database == ":memory:":
        raise BackupError(f"{db_url}: an in-memory database cannot be backed up")
    return Path(url.database)


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


# ----------------------------------------------------------------------------- backup


@dataclass
class BackupResult:
    """What :func:`create_backup` wrote.

    Attributes:
        path: the archive.
        manifest: its manifest (see the module docstring).
    """

    path: Path
    manifest: dict[str, Any]

    @property
    def skipped(self) -> list[dict[str, str]]:
        """What was left out (``path`` and ``why``), e.g. a part still transferring."""
        out: list[dict[str, str]] = self.manifest["skipped"]
        return out


class _Hashing(io.RawIOBase):
    """A file read through SHA-256 (what tarfile copies into the archive)."""

    def __init__(self, fh: BinaryIO) -> None:
        self.fh = fh
        self.sha = hashlib.sha256()

    def readable(self) -> bool:
        return True

    def read(self, n: int = -1) -> bytes:
        b = self.fh.read(n)
        self.sha.update(b)
        return b


def _add_file(tar: tarfile.TarFile, name: str, path: Path) -> dict[str, Any]:
    with open(path, "rb") as fh:
        st = os.fstat(fh.fileno())  # the file opened: an atomic replace after it is harmless
        info = tarfile.TarInfo(name)
        info.size, info.mtime, info.mode = st.st_size, int(st.st_mtime), 0o600
        src = _Hashing(fh)
        tar.addfile(info, src)  # type: ignore[arg-type]
    return {"name": name, "size": st.st_size, "sha256": src.sha.hexdigest()}


def _add_bytes(tar: tarfile.TarFile, name: str, data: bytes) -> dict[str, Any]:
    info = tarfile.TarInfo(name)
    info.size, info.mtime, info.mode = len(data), int(time.time()), 0o600
    tar.addfile(info, io.BytesIO(data))
    return {"name": name, "size": len(data), "sha256": hashlib.sha256(data).hexdigest()}


def _is_part_dir(d: Path, rel: PurePosixPath) -> bool:
    # recordings/<rec_id>/<node_id>/ holding (or receiving) a node's part; not the
    # report reference beside them (its meta.json made it look like a part in transfer)
    return (len(rel.parts) == 3 and rel.parts[0] == "recordings"
            and rel.parts[2] != erasures.REPORT_REFERENCE_DIR
            and any((d / n).exists() for n in (".incoming", "manifest.json", "meta.json",
                                               "frames.bin")))


def _walk(data_dir: Path, skipped: list[dict[str, str]],
          skip_files: set[Path]) -> Iterator[tuple[PurePosixPath, Path]]:
    """Every file to copy (relative name, path), sorted; fills ``skipped``."""
    for root, dirs, files in os.walk(data_dir):
        here = Path(root)
        rel_dir = PurePosixPath(here.relative_to(data_dir).as_posix())
        dirs.sort()
        keep = []
        for d in dirs:
            rel = rel_dir / d
            if (here / d).is_symlink():
                skipped.append({"path": str(rel), "why": "a symbolic link (not followed)"})
            elif d.startswith(".") and d.endswith(".tmp") and not _is_part_dir(here / d, rel):
                continue  # work in progress (an upload being checked), like *.tmp files
            elif _is_part_dir(here / d, rel) and not (
                    (here / d / "manifest.json").is_file()
                    and not (here / d / ".incoming").exists()):
                skipped.append({"path": str(rel),
                                "why": "part still being transferred (not complete on the "
                                       "server): back up again once it is complete"})
            else:
                keep.append(d)
        dirs[:] = keep
        for f in sorted(files):
            p, rel = here / f, rel_dir / f
            if p in skip_files or (rel_dir == PurePosixPath(".") and f in _DB_FILES):
                continue
            if f.endswith(".tmp") or rel == PurePosixPath(erasures.LOG_NAME):
                continue  # half-written atomic writes; the erasure log goes last
            if p.is_symlink() or not p.is_file():
                skipped.append({"path": str(rel), "why": "not a regular file"})
                continue
            yield rel, p


def _snapshot_sqlite(src: Path, dst: Path) -> dict[str, Any]:
    """A consistent copy of a live SQLite database (online backup API), with its
    revision, row counts and integrity."""
    if not src.is_file():
        raise BackupError(f"no database at {src}: is this the server's data folder? (give "
                          "--data-dir, or set GAITRIG_DATA_DIR / GAITRIG_DATABASE_URL)")
    s = sqlite3.connect(f"{src.resolve().as_uri()}?mode=ro", uri=True, timeout=30)
    d = sqlite3.connect(dst)
    try:
        at = _now()
        s.backup(d)  # one step: one read transaction, so one instant of the database
        d.execute("PRAGMA journal_mode=DELETE")  # the copy is one self-contained file
        info = {"dialect": "sqlite", "member": DB_MEMBER, "snapshot_at": at}
        info.update(_db_facts(d))
    finally:
        d.close()
        s.close()
    if info["integrity"] != "ok":
        raise BackupError(f"the database {src} fails its integrity check "
                          f"({info['integrity'][:200]}): do not overwrite your older backups; "
                          "copy the data folder as it is and ask for help")
    return info


def _db_facts(c: sqlite3.Connection) -> dict[str, Any]:
    tables = {r[0] for r in c.execute("SELECT name FROM sqlite_master WHERE type='table'")}
    rev = None
    if "alembic_version" in tables:
        row = c.execute("SELECT version_num FROM alembic_version").fetchone()
        rev = row[0] if row else None
    counts = {t: int(c.execute(f'SELECT count(*) FROM "{t}"').fetchone()[0])
              for t in _COUNTED if t in tables}
    check = "; ".join(r[0] for r in c.execute("PRAGMA integrity_check"))
    return {"alembic_revision": rev, "counts": counts, "integrity": check}


def _server_db_facts(db_url: str) -> tuple[set[str], str | None, dict[str, int]]:
    """Tables, alembic revision and row counts of a database server's database."""
    from sqlalchemy import create_engine, inspect, text

    engine = create_engine(db_url)
    try:
        with engine.connect() as c:
            tables = set(inspect(c).get_table_names())
            rev = (c.execute(text("SELECT version_num FROM alembic_version")).scalar()
                   if "alembic_version" in tables else None)
            counts = {t: int(c.execute(text(f'SELECT count(*) FROM "{t}"')).scalar() or 0)
                      for t in _COUNTED if t in tables}
    finally:
        engine.dispose()
    return tables, rev, counts


def _read_server_database(db_url: str, db: dict[str, Any], notes: list[str]) -> None:
    """Record in ``db`` the revision and row counts of the (PostgreSQL) database the files
    go with, as read now: not a snapshot (``pg_dump`` makes that), a reference for the
    restore. Notes what cannot be read and a missing ``pg_dump``."""
    from sqlalchemy.exc import SQLAlchemyError

    try:
        _tables, db["alembic_revision"], db["counts"] = _server_db_facts(db_url)
        db["read_at"] = _now()
    except (SQLAlchemyError, ImportError) as exc:
        notes.append("the database could not be read to record its revision and row counts "
                     f"({str(exc).splitlines()[0][:200]}); the files were backed up")
    if shutil.which("pg_dump") is None:
        notes.append(f"pg_dump is not installed on this machine: install {PG_CLIENT}, or "
                     "run pg_dump on a machine that has it")


def backup_name(now: datetime | None = None) -> str:
    """The archive name used when the destination is a folder."""
    return f"gaitrig-backup-{(now or datetime.now(UTC)):%Y%m%d-%H%M%S}.tar"


def create_backup(data_dir: Path, dest: Path, db_url: str | None = None) -> BackupResult:
    """Back up a (possibly running) server's data folder and database into one archive.

    Args:
        data_dir: the server's data folder.
        dest: the archive to write (``.tar``), or an existing folder to write
            ``gaitrig-backup-<UTC time>.tar`` into. Never overwritten.
        db_url: the database URL (``Settings.db_url``); default the SQLite file of
            ``data_dir``.

    Returns:
        The archive and its manifest.

    Raises:
        BackupError: no data folder or database, the destination exists or lies inside
            the data folder, the database fails its integrity check.
    """
    data_dir = Path(data_dir).resolve()
    if not data_dir.is_dir():
        raise BackupError(f"no data folder at {data_dir} (give --data-dir or set "
                          "GAITRIG_DATA_DIR)")
    dest = Path(dest)
    if dest.is_dir():
        dest = dest / backup_name()
    dest = dest.resolve()
    if dest.exists():
        raise BackupError(f"{dest} exists already: a backup never overwrites a file; give a "
                          "new name or a folder")
    if dest.is_relative_to(data_dir):
        raise BackupError(f"{dest} is inside the data folder {data_dir}: put backups on "
                          "another disk (or at least outside the data folder)")
    if not dest.parent.is_dir():
        raise BackupError(f"the folder {dest.parent} does not exist")
    db_url = db_url or f"sqlite:///{data_dir / 'gaitrig.sqlite3'}"
    db_file = sqlite_path(db_url)
    created = _now()
    skipped: list[dict[str, str]] = []
    entries: list[dict[str, Any]] = []
    notes: list[str] = []
    partial = dest.with_name(dest.name + ".partial")
    try:
        with tarfile.open(partial, "w", format=tarfile.PAX_FORMAT) as tar:
            if db_file is not None:
                with tempfile.TemporaryDirectory(dir=dest.parent, prefix=".gaitrig-db-") as t:
                    snap = Path(t) / "gaitrig.sqlite3"
                    db = _snapshot_sqlite(db_file, snap)
                    entries.append(_add_file(tar, DB_MEMBER, snap))
            else:
                db = {"dialect": make_url(db_url).get_backend_name(), "member": None,
                      "alembic_revision": None, "counts": {}, "how": PG_HOW}
                notes.append(PG_HOW)
                _read_server_database(db_url, db, notes)
            skip = {db_file.resolve()} if db_file is not None else set()
            for rel, path in _walk(data_dir, skipped, skip):
                try:
                    entries.append(_add_file(tar, FILES + str(rel), path))
                except FileNotFoundError:  # deleted since the walk saw it
                    skipped.append({"path": str(rel), "why": "deleted during the backup"})
            _check_parts(data_dir, entries, notes)
            log = erasures.log_path(data_dir)
            if log.is_file():  # last: it names every deletion made during the backup
                entries.append(_add_bytes(tar, ERASURE_MEMBER, log.read_bytes()))
            files = [e for e in entries if e["name"].startswith(FILES)]
            manifest = {
                "format": FORMAT, "gaitrig_version": gaitrig_version(),
                "created_at": created, "finished_at": _now(),
                "alembic_revision": db.get("alembic_revision"), "database": db,
                "counts": {**db.get("counts", {}), "files": len(files),
                           "file_bytes": sum(e["size"] for e in files)},
                "members": entries, "skipped": skipped, "notes": notes,
            }
            _add_bytes(tar, MANIFEST, json.dumps(manifest, indent=1).encode())
        with open(partial, "rb") as fh:
            os.fsync(fh.fileno())
        os.chmod(partial, 0o600)  # health data: readable by its owner only
        os.replace(partial, dest)
        _sync_tree(dest.parent, files=False)  # the name too: a cron job prunes after this
    except BaseException:
        partial.unlink(missing_ok=True)
        raise
    return BackupResult(dest, manifest)


def _check_parts(data_dir: Path, entries: list[dict[str, Any]], notes: list[str]) -> None:
    """Compare each part file's SHA-256 with the node's manifest (bit rot on the server)."""
    by_name = {e["name"]: e for e in entries}
    for e in entries:
        name = e["name"]
        if not (name.startswith(FILES + "recordings/") and name.endswith("/manifest.json")):
            continue
        folder = name[: -len("manifest.json")]
        try:  # a few kB, immutable once the part is complete
            man = json.loads((data_dir / name[len(FILES):]).read_text())
        except (OSError, ValueError):
            continue
        for f in man.get("files", []) if isinstance(man, dict) else []:
            got = by_name.get(folder + str(f.get("name")))
            if got is not None and f.get("sha256") and got["sha256"] != f["sha256"]:
                notes.append(f"{folder[len(FILES):]}{f['name']}: its SHA-256 differs from the "
                             "node's manifest (damaged on the server's disk); copied as it is")


# ----------------------------------------------------------------------------- reading


@dataclass
class VerifyResult:
    """What :func:`verify_backup` found.

    Attributes:
        manifest: the archive's manifest.
        problems: every mismatch found ([] when the archive is good).
        checked: members whose SHA-256 was checked.
    """

    manifest: dict[str, Any]
    problems: list[str] = field(default_factory=list)
    checked: int = 0

    @property
    def ok(self) -> bool:
        return not self.problems


def _open(archive: Path) -> tarfile.TarFile:
    archive = Path(archive)
    if not archive.is_file():
        raise BackupError(f"no backup archive at {archive}")
    try:
        return tarfile.open(archive, "r:")
    except tarfile.TarError as exc:
        raise BackupError(f"{archive} is not a gaitrig backup (not an uncompressed tar "
                          f"archive: {exc}); give the .tar file that gaitrig backup wrote "
                          "(decrypt it first if you encrypted it)") from exc


def read_manifest(tar: tarfile.TarFile, archive: Path) -> dict[str, Any]:
    """The manifest of an open archive.

    Raises:
        BackupError: the archive is not a gaitrig backup or of a newer format.
    """
    try:
        fh = tar.extractfile(MANIFEST)
        man = json.loads(fh.read()) if fh is not None else None
    except (KeyError, ValueError, tarfile.TarError) as exc:
        raise BackupError(f"{archive} is not a gaitrig backup (no readable {MANIFEST}): "
                          "give an archive written by gaitrig backup") from exc
    if not isinstance(man, dict) or not str(man.get("format", "")).startswith(
            "gaitrig-backup/"):
        raise BackupError(f"{archive} is not a gaitrig backup ({MANIFEST} of another format)")
    if man["format"] != FORMAT:
        raise BackupError(f"{archive} is a {man['format']} archive; this gaitrig reads "
                          f"{FORMAT}: restore it with a newer gaitrig")
    bad = _manifest_fault(man)
    if bad:
        raise BackupError(f"{archive} has a damaged {MANIFEST} ({bad}): it cannot be checked "
                          "or restored; use another backup")
    return man


def _manifest_fault(man: dict[str, Any]) -> str | None:
    """What is wrong with the fields the manifest's readers use (None: nothing). The
    manifest is the one member no checksum covers."""
    def dicts(v: Any) -> bool:
        return isinstance(v, list) and all(isinstance(x, dict) for x in v)

    for key, ok in (("created_at", lambda v: isinstance(v, str)),
                    ("gaitrig_version", lambda v: isinstance(v, str)),
                    ("database", lambda v: isinstance(v, dict)),
                    ("counts", lambda v: isinstance(v, dict)),
                    ("members", dicts), ("skipped", dicts),
                    ("notes", lambda v: isinstance(v, list)),
                    ("alembic_revision", lambda v: v is None or isinstance(v, str))):
        if key not in man or not ok(man[key]):
            return f"no valid {key!r}"
    for e in man["members"]:
        if not (isinstance(e.get("name"), str) and type(e.get("size")) is int
                and isinstance(e.get("sha256"), str)):
            return f"'members' entry {str(e)[:80]!r} lacks a name, size or sha256"
    if any(not {"path", "why"} <= set(s) for s in man["skipped"]):
        return "a 'skipped' entry lacks its path or why"
    return None


def _safe_rel(name: str) -> PurePosixPath:
    rel = PurePosixPath(name)
    if rel.is_absolute() or ".." in rel.parts or not rel.parts:
        raise BackupError(f"unsafe path {name!r} in the archive: it is damaged or not a "
                          "gaitrig backup")
    return rel


def _copy_hashing(src: IO[bytes], dst: IO[bytes] | None) -> tuple[int, str]:
    sha, n = hashlib.sha256(), 0
    while b := src.read(_BUF):
        sha.update(b)
        n += len(b)
        if dst is not None:
            dst.write(b)
    return n, sha.hexdigest()


def _members(tar: tarfile.TarFile, man: dict[str, Any], problems: list[str],
             want: Callable[[str], Path | None]) -> int:
    """Check every member against the manifest, writing each one ``want`` names to its
    path (hashed as written). Returns how many were checked."""
    expected = {e["name"]: e for e in man.get("members", [])}
    seen: set[str] = set()
    checked = 0
    for info in tar:
        if info.name == MANIFEST:
            continue
        _safe_rel(info.name)
        e = expected.get(info.name)
        if e is None:
            problems.append(f"{info.name}: in the archive but not in its manifest")
            continue
        if not info.isfile():
            problems.append(f"{info.name}: not a regular file")
            continue
        seen.add(info.name)
        # bounds what is written by the archive's own size: a sparse member unpacks to as
        # many zeros as its header claims, and the checksum is known only once written
        if info.issparse():
            problems.append(f"{info.name}: a sparse file (gaitrig backup writes none)")
            continue
        if info.size != e["size"]:
            problems.append(f"{info.name}: {info.size} bytes, the manifest says {e['size']}: "
                            "the archive is damaged")
            continue
        target = want(info.name)
        src = tar.extractfile(info)
        assert src is not None
        if target is not None:
            target.parent.mkdir(parents=True, exist_ok=True)
            with open(target, "wb") as out:
                size, sha = _copy_hashing(src, out)
        else:
            size, sha = _copy_hashing(src, None)
        checked += 1
        if size != e["size"] or sha != e["sha256"]:
            problems.append(f"{info.name}: checksum mismatch (SHA-256 {sha[:12]}…, manifest "
                            f"{str(e['sha256'])[:12]}…): the archive is damaged")
    for name in sorted(set(expected) - seen):
        problems.append(f"{name}: listed in the manifest but missing from the archive")
    return checked


def verify_backup(archive: Path) -> VerifyResult:
    """Check every member's SHA-256 and the database's integrity, restoring nothing.

    Raises:
        BackupError: not a gaitrig backup (what is damaged inside one is reported in
            :attr:`VerifyResult.problems`).
    """
    archive = Path(archive)
    with _open(archive) as tar, tempfile.TemporaryDirectory(prefix="gaitrig-verify-") as t:
        man = read_manifest(tar, archive)
        res = VerifyResult(man)
        db_tmp = Path(t) / "gaitrig.sqlite3"
        try:
            res.checked = _members(tar, man, res.problems,
                                   lambda n: db_tmp if n == DB_MEMBER else None)
        except (tarfile.TarError, OSError) as exc:
            res.problems.append(f"the archive is damaged or cut short ({exc})")
        if man["database"].get("member") and db_tmp.is_file():
            try:
                _check_integrity(db_tmp, archive)
            except BackupError as exc:
                res.problems.append(f"{DB_MEMBER}: {exc}")
    return res


# ----------------------------------------------------------------------------- restore


@dataclass
class RestoreResult:
    """What :func:`restore_backup` did.

    Attributes:
        data_dir: the restored data folder.
        manifest: the archive's manifest.
        revision_before: the database's alembic revision in the archive.
        revision_after: after the migration (the running gaitrig's head).
        erased_recordings: recordings the erasure logs deleted again (rows and files).
        erased_references: reference recordings deleted on their own that the erasure
            logs deleted again.
        erasures_applied: entries of the logs applied.
        notes: what the operator must know (PostgreSQL, parts left out of the backup).
        with_current_log: a current erasure log was given (not --without-deletion-log).
    """

    data_dir: Path
    manifest: dict[str, Any]
    revision_before: str | None = None
    revision_after: str | None = None
    erased_recordings: list[str] = field(default_factory=list)
    erased_references: int = 0
    erasures_applied: int = 0
    notes: list[str] = field(default_factory=list)
    with_current_log: bool = True


#: What a server's data folder holds besides its database (a PostgreSQL server's holds no
#: ``gaitrig.sqlite3``): recordings, references, calibrations, the live recording list.
_DATA_FOLDER_ENTRIES = ("recordings", "references", "calibrations", "recordings.json",
                        "deletions.json")


def _no_log_message(folder: Path) -> str:
    """What to do about a ``--deletion-log`` folder holding no erasure log."""
    what_else = ("give the folder that holds its erasure log (the data folder the server "
                 f"ran with, GAITRIG_DATA_DIR), the {erasures.LOG_NAME} itself, or a newer "
                 "backup")
    if any((folder / n).exists() for n in _DATA_FOLDER_ENTRIES):
        # a server's data folder, of a server whose database is PostgreSQL (no SQLite
        # file): its log is written here on the first deletion, so none means none yet
        return (f"{folder} looks like the data folder of a server using PostgreSQL (no "
                f"gaitrig.sqlite3 in it) and holds no {erasures.LOG_NAME}: that server then "
                "never deleted anything (the log is written there on the first deletion), "
                "so restore with --without-deletion-log instead; if it did delete, the log "
                f"is elsewhere: {what_else}")
    return (f"{folder} holds no {erasures.LOG_NAME} and is not a server's data folder: "
            f"{what_else}. A server using PostgreSQL that never deleted anything has no log: "
            "then restore with --without-deletion-log instead")


def read_erasure_log(path: Path) -> list[erasures.Erasure]:
    """The erasure log in ``path``: a log file (``erasures.jsonl``), a data folder, or a
    (newer) backup archive, which carries the log as it was when it was made.

    Raises:
        BackupError: none found there, or not readable as one.
    """
    path = Path(path)
    try:
        if path.is_dir():
            if (path / "gaitrig.sqlite3").is_file() and not erasures.log_path(path).exists():
                return []  # a server's data folder where nothing was deleted yet
            if not erasures.log_path(path).is_file():
                raise BackupError(_no_log_message(path))
            return erasures.read(path)
        if path.is_file() and tarfile.is_tarfile(path):
            with _open(path) as tar:
                read_manifest(tar, path)
                try:
                    fh = tar.extractfile(ERASURE_MEMBER)
                except KeyError:
                    return []  # that server had deleted nothing yet
                return erasures.parse(fh.read().decode() if fh else "", f"{path}")
        if path.is_file():
            return erasures.parse(path.read_text(), str(path))
    except (ValueError, UnicodeDecodeError) as exc:
        raise BackupError(f"{path}: {exc}") from exc
    raise BackupError(f"no erasure log at {path}")


def restore_backup(archive: Path, data_dir: Path, deletion_logs: list[Path],
                   *, without_deletion_log: bool = False, force: bool = False,
                   db_url: str | None = None, actor: str = "",
                   client: str = "") -> RestoreResult:
    """Restore an archive into an empty data folder, bring the database to the current
    alembic head and delete again everything the erasure logs say was deleted.

    The archive is checked completely while it is unpacked into a folder beside
    ``data_dir``; only when everything matched are its contents moved into
    ``data_dir``. Files of erased recordings are never written.

    Args:
        archive: the backup.
        data_dir: the data folder to restore into: empty or missing (or ``force``).
        deletion_logs: the current erasure logs (the server's ``erasures.jsonl``, its
            data folder, or a newer backup); the archive's own log is always applied.
        without_deletion_log: restore without a current log (the operator states there
            is none: nothing was deleted since the backup, or the log is lost).
        force: replace what ``data_dir`` holds (its erasure log is applied first).
        db_url: for an archive without a database (PostgreSQL): that database, restored
            with ``pg_restore`` beforehand; it is migrated and the erasures applied to it.
        actor: who restores (audit trail). client: from where.

    Raises:
        BackupError: a damaged or wrong archive, a non-empty folder without ``force``,
            no erasure log and no ``without_deletion_log``; nothing is changed then.
    """
    archive, data_dir = Path(archive).resolve(), Path(data_dir).resolve()
    with _open(archive) as tar:
        man = read_manifest(tar, archive)
    current: list[list[erasures.Erasure]] = [read_erasure_log(p) for p in deletion_logs]
    existing = data_dir.is_dir() and any(data_dir.iterdir())
    if data_dir.exists() and not data_dir.is_dir():
        raise BackupError(f"{data_dir} is a file, not a folder")
    if existing and not force:
        raise BackupError(f"{data_dir} is not empty: restore into an empty folder, or give "
                          "--force to replace everything in it (a restore never merges)")
    if existing:
        if archive.is_relative_to(data_dir):
            raise BackupError(f"the archive {archive} lies inside the folder it would replace "
                              f"({data_dir}), and would be deleted with it: move it out first")
        if _in_use(data_dir / "gaitrig.sqlite3"):
            raise BackupError(f"the database in {data_dir} is open in another program (a "
                              "running gaitrig server?): stop the server, then restore")
        try:  # the replaced server's own deletions
            current.append(erasures.read(data_dir))
        except (ValueError, UnicodeDecodeError) as exc:
            raise BackupError(f"{exc}: the erasure log of the folder to replace is damaged; "
                              "repair that line (or move the log aside and give a copy of "
                              "it with --deletion-log once repaired)") from exc
    if not current and not without_deletion_log:
        raise BackupError(
            "give the current erasure log with --deletion-log (the server's data folder or "
            f"its {erasures.LOG_NAME}, or the newest backup): a backup made before a subject "
            "was deleted would bring that subject back. Only if no deletion was made since "
            "this backup, or the log is lost, give --without-deletion-log instead")
    has_db = bool(man["database"].get("member"))
    if not has_db and not db_url:
        raise BackupError(
            "this backup holds no database (the server used PostgreSQL): restore the "
            "database's pg_dump with pg_restore first, then run the restore again with "
            "GAITRIG_DATABASE_URL set to it (it is migrated and the deletions applied to it)")
    res = RestoreResult(data_dir, man, revision_before=man.get("alembic_revision"),
                        with_current_log=bool(current))
    if not has_db:
        res.revision_before = _check_restored_database(str(db_url), man, res.notes)
    elif db_url and make_url(db_url).get_backend_name() != "sqlite":
        res.notes.append(
            f"this backup holds a SQLite database, restored into {data_dir / 'gaitrig.sqlite3'}"
            f"; GAITRIG_DATABASE_URL names another database ({make_url(db_url).get_backend_name()}"
            "), which was left as it was: unset GAITRIG_DATABASE_URL to serve the restored one")
    created = not data_dir.exists()
    data_dir.mkdir(parents=True, exist_ok=True)
    # staged on the data folder's own file system, so that moving it in is a rename: beside
    # it, or inside it when it is a mount point (the docker set-up's /data volume)
    near = (data_dir.parent if os.stat(data_dir).st_dev == os.stat(data_dir.parent).st_dev
            else data_dir)
    stage = Path(tempfile.mkdtemp(prefix=f".{data_dir.name}.restoring-", dir=near))
    ok = False
    try:
        with _open(archive) as tar:
            own: list[erasures.Erasure] = []
            try:
                fh = tar.extractfile(ERASURE_MEMBER)
                own = erasures.parse(fh.read().decode() if fh else "", f"{archive}")
            except KeyError:
                pass
            entries = erasures.merge(own, *current)
            erased = erasures.erased_keys(entries)
            left_out: dict[str, list[str]] = {}  # erased recordings found in the archive
            problems: list[str] = []
            _members(tar, man, problems, lambda n: _target(stage, n, erased, left_out))
        if problems:
            raise BackupError(f"{archive} is damaged; nothing was restored: "
                              + "; ".join(problems[:5])
                              + (f" (and {len(problems) - 5} more)" if len(problems) > 5 else ""))
        if has_db:
            _check_integrity(stage / "gaitrig.sqlite3", archive)
        # the merged log goes with the data: the next backup carries it on
        _write_log(stage, entries)
        url = f"sqlite:///{stage / 'gaitrig.sqlite3'}" if has_db else str(db_url)
        _finish_database(url, stage, entries, res, actor, client, archive, left_out)
        _sync_tree(stage)  # on the disk before the data folder names it (a power cut)
        if _in_use(data_dir / "gaitrig.sqlite3"):  # again: unpacking took a while
            raise BackupError(f"the database in {data_dir} was opened by another program "
                              "(a gaitrig server started?) during the restore: stop it, then "
                              "restore again; nothing was changed")
        _install(stage, data_dir)
        _sync_tree(data_dir, files=False)
        ok = True
    finally:
        shutil.rmtree(stage, ignore_errors=True)
        if created and not ok:
            shutil.rmtree(data_dir, ignore_errors=True)
    res.notes += [f"{s['path']}: not in the backup ({s['why']})" for s in man["skipped"]]
    if not has_db:
        res.notes.append("the database is the PostgreSQL database of GAITRIG_DATABASE_URL "
                         "(restored by you with pg_restore); it was migrated and the "
                         "deletions applied to it")
    return res


def _check_restored_database(db_url: str, man: dict[str, Any], notes: list[str]) -> str | None:
    """Check the (PostgreSQL) database an archive without one is restored with: restored
    already (not empty) and used by no one else (a running server). Notes row counts that
    differ from the backup's. Returns its alembic revision.

    Raises:
        BackupError: it cannot be reached, is empty, or is in use; nothing was changed.
    """
    from sqlalchemy import create_engine, text
    from sqlalchemy.exc import SQLAlchemyError

    shown = make_url(db_url).render_as_string(hide_password=True)
    try:
        tables, rev, counts = _server_db_facts(db_url)
        others: list[str] = []
        if make_url(db_url).get_backend_name() == "postgresql":
            engine = create_engine(db_url)
            try:
                with engine.connect() as c:
                    others = [f"{r[0] or 'a program'} from {r[1] or 'this machine'}"
                              for r in c.execute(text(
                                  "SELECT application_name, client_addr FROM pg_stat_activity "
                                  "WHERE datname = current_database() AND pid <> "
                                  "pg_backend_pid() AND backend_type = 'client backend'"))]
            finally:
                engine.dispose()
    except (SQLAlchemyError, ImportError) as exc:
        raise BackupError(f"the database {shown} (GAITRIG_DATABASE_URL) cannot be reached "
                          f"({str(exc).splitlines()[0][:200]}); nothing was restored") from exc
    if "alembic_version" not in tables or "subjects" not in tables:
        raise BackupError(
            f"the database {shown} (GAITRIG_DATABASE_URL) is empty: this backup holds the "
            "files only; restore the database's pg_dump into it first (pg_restore "
            "--no-owner -d <that URL without '+psycopg'> gaitrig.pgdump), then run gaitrig "
            "restore again. Nothing was restored")
    if others:
        raise BackupError(
            f"the database {shown} is in use ({len(others)} other connection(s): "
            f"{', '.join(sorted(set(others))[:3])}; a running gaitrig server?): stop the "
            "server, then restore; nothing was restored")
    had = man["database"].get("counts") or {}
    differ = [f"{t} {counts.get(t, 0)} (backup {had[t]})" for t in _COUNTED
              if t in had and t not in ("users", "audit_events") and counts.get(t, 0) != had[t]]
    if differ:
        notes.append("the database's rows differ from those when the files were backed up ("
                     + ", ".join(differ) + "): check that its pg_dump is the one taken with "
                     "this backup")
    return rev


def _sync_tree(root: Path, files: bool = True) -> None:
    """fsync every file (unless not ``files``) and folder below ``root``, and ``root``."""
    def sync(p: Path, flags: int) -> None:
        fd = os.open(p, flags)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)

    for here, _dirs, names in os.walk(root) if files else [(str(root), [], [])]:
        for n in names:
            if not os.path.islink(os.path.join(here, n)):
                sync(Path(here, n), os.O_RDONLY)
        sync(Path(here), os.O_RDONLY | os.O_DIRECTORY)


def _install(stage: Path, data_dir: Path) -> None:
    """Replace what ``data_dir`` holds by what ``stage`` holds (both on one file system).

    The old contents are moved aside, not deleted, until the new ones are all in: a
    failure on the way (a full disk, an interrupt) moves everything back. The database
    goes in last, so a folder left half-done by a crash holds none.
    """
    aside = Path(tempfile.mkdtemp(prefix=f".{data_dir.name}.replaced-", dir=stage.parent))
    old: list[str] = []
    new: list[str] = []
    try:
        for p in sorted(data_dir.iterdir()):
            if p not in (stage, aside):
                os.replace(p, aside / p.name)
                old.append(p.name)
        for p in sorted(stage.iterdir(), key=lambda q: (q.name == "gaitrig.sqlite3", q.name)):
            os.replace(p, data_dir / p.name)
            new.append(p.name)
    except BaseException:
        for n in reversed(new):
            os.replace(data_dir / n, stage / n)
        for n in reversed(old):
            os.replace(aside / n, data_dir / n)
        shutil.rmtree(aside, ignore_errors=True)
        raise
    shutil.rmtree(aside, ignore_errors=True)


def _in_use(db: Path) -> bool:
    """Whether another process has the SQLite database open (in WAL mode, as the server
    opens it): every connection holds a read lock on the "DMS" byte (128) of its
    ``-shm`` file, so a write lock on it is refused while one is open."""
    import fcntl
    import struct

    shm = db.with_name(db.name + "-shm")
    if not shm.is_file():
        return False
    try:
        fd = os.open(shm, os.O_RDWR)
    except OSError:
        return False
    try:
        lock = struct.pack("hhqqi", fcntl.F_WRLCK, os.SEEK_SET, 128, 1, 0)
        try:
            got = struct.unpack("hhqqi", fcntl.fcntl(fd, fcntl.F_GETLK, lock))
        except OSError:
            return False
        return bool(got[0] != fcntl.F_UNLCK)
    finally:
        os.close(fd)


def _check_integrity(db: Path, archive: Path) -> None:
    try:
        c = sqlite3.connect(db)
        try:
            check = _db_facts(c)["integrity"]
        finally:
            c.close()
    except sqlite3.DatabaseError as exc:
        check = str(exc)
    if check != "ok":
        raise BackupError(f"the database in {archive} fails PRAGMA integrity_check "
                          f"({check[:200]}); nothing was restored: use another backup")


def _target(stage: Path, name: str, erased: dict[str, list[str]],
            left_out: dict[str, list[str]]) -> Path | None:
    if name == DB_MEMBER:
        return stage / "gaitrig.sqlite3"
    if name == ERASURE_MEMBER or not name.startswith(FILES):
        return None  # the merged log is written after; the manifest stays in the archive
    rel = _safe_rel(name[len(FILES):])
    if len(rel.parts) >= 2 and rel.parts[0] in ("recordings", "references"):
        nodes = erased.get(erasures.rec_key(rel.parts[1]))
        if nodes is not None:
            left_out[rel.parts[1]] = nodes
            return None  # a deleted recording's files are never written again
    return stage.joinpath(*rel.parts)


def _write_log(stage: Path, entries: list[erasures.Erasure]) -> None:
    lines = []
    for e in entries:
        lines.append({"id": e.id, "state": "started", "at": e.at,
                      "rows": [list(r) for r in e.rows], "recordings": e.recordings})
        if e.state != "started":
            lines.append({"id": e.id, "state": e.state, "at": e.at})
    if lines:
        erasures.log_path(stage).write_text(
            "".join(json.dumps(x, separators=(",", ":")) + "\n" for x in lines))


def _finish_database(url: str, stage: Path, entries: list[erasures.Erasure],
                     res: RestoreResult, actor: str, client: str, archive: Path,
                     left_out: dict[str, list[str]]) -> None:
    """Migrate to head, apply the erasures, tombstone the erased recordings (the server
    finishes their node copies and live entries when it starts), audit, purge."""
    from sqlalchemy import text

    from app.db import audit
    from app.db.base import make_engine, make_session_factory, purge_deleted
    from app.server.storage import StorageLayout

    engine = make_engine(url)  # migrates to the current head
    try:
        with engine.connect() as c:
            res.revision_after = c.execute(text("SELECT version_num FROM alembic_version")
                                           ).scalar()
        with make_session_factory(engine)() as db:
            ref_files = erasures.reference_files(db, entries)  # before apply drops the rows
            plan = erasures.apply(db, entries)
            for rel in ref_files:  # reference imports deleted on their own
                (stage / rel).unlink(missing_ok=True)
            res.erased_references = len(ref_files) + _drop_report_references(stage, entries)
            for rec_id, nodes in {**left_out, **_live_entries(stage, entries)}.items():
                plan[rec_id] = sorted(set(plan.get(rec_id, [])) | set(nodes))
            res.erasures_applied = sum(1 for e in entries if e.state != "void")
            res.erased_recordings = sorted(plan)
            layout = StorageLayout(stage)
            for rec_id in plan:
                layout.delete_recording(rec_id)  # e.g. an analysis written after the rows
            if plan:
                layout.add_tombstones(plan)
            audit.record(db, actor or "(command line)", "restore", archive.name[:200],
                         f"backup of {res.manifest.get('created_at')}, revision "
                         f"{res.revision_before} -> {res.revision_after}; "
                         f"{len(plan)} deleted recordings kept deleted"
                         + (f", {res.erased_references} deleted references"
                            if res.erased_references else "")
                         + ("" if res.with_current_log else
                            "; WITHOUT a current erasure log (--without-deletion-log)"),
                         client)
        if engine.dialect.name == "sqlite":
            with engine.connect() as c:  # no page of an erased row left in the file
                c.exec_driver_sql("VACUUM")
            purge_deleted(engine)
    finally:
        engine.dispose()


def _drop_report_references(stage: Path, entries: list[erasures.Erasure]) -> int:
    """Delete the report references (``recordings/<id>/reference/``, no row) the entries
    deleted, when their upload time matches (a later upload is kept). Returns how many."""
    erased = erasures.erased_report_references(entries)
    if not erased:
        return 0
    n = 0
    for folder in sorted((stage / "recordings").glob(f"*/{erasures.REPORT_REFERENCE_DIR}")):
        key = erasures.rec_key(folder.parent.name)
        if folder.is_dir() and (key, erasures.report_reference_uploaded(folder)) in erased:
            shutil.rmtree(folder)
            n += 1
    return n


def _live_entries(stage: Path, entries: list[erasures.Erasure]) -> dict[str, list[str]]:
    """The erased recordings among the hub's live entries (``recordings.json``): an
    unfiled recording has no row and maybe no files, only its entry."""
    erased = erasures.erased_keys(entries)
    try:
        raw = json.loads((stage / "recordings.json").read_text())
    except (OSError, ValueError):
        return {}
    out: dict[str, list[str]] = {}
    for r in raw if isinstance(raw, list) else []:
        rid = str(r.get("id", "")) if isinstance(r, dict) else ""
        if rid and erasures.rec_key(rid) in erased:
            out[rid] = sorted(set(erased[erasures.rec_key(rid)]) | set(r.get("parts") or {}))
    return out


def last_backup(db: Any) -> datetime | None:
    """When the last successful backup was made (from the audit trail), or None."""
    from app.db.models import AuditEvent

    at = db.scalar(select(AuditEvent.at).where(AuditEvent.action == "backup")
                   .order_by(desc(AuditEvent.id)).limit(1))
    if at is not None and at.tzinfo is None:
        at = at.replace(tzinfo=UTC)
    return at  # type: ignore[no-any-return]
