"""Start-up clean-up of what a killed server left in its data folder.

An upload or a write in progress is made under a temporary name ending in ``.tmp``
(backups leave those out) and renamed into place when done; a server killed in the middle
leaves the temporary file. The next upload to the same recording removed such leftovers
older than a day; a recording never uploaded to again kept them for good. The server
now also removes them when it starts (in a worker thread, :func:`clean_stale`):

* ``references/<rec_id>/.<name>.upload.tmp`` — a reference import being uploaded;
* ``references/<rec_id>/<name>`` named by no ``reference_imports`` row — a reference
  import put in place whose row never committed (the file lands before the row);
* ``recordings/<rec_id>/.reference-upload-*.tmp/`` — a report reference being checked
  (one named ``...-deleted-*`` holds a reference whose deletion committed: removed
  whatever its age);
* ``recordings/<rec_id>/.*.tmp`` and ``recordings/<rec_id>/analysis/.*.tmp`` — an
  analysis or the sensor poses being written.

Only what is older than :data:`STALE_S` goes (no upload or write lasts that long), so an
upload in progress is never touched; nothing inside a part's folder is looked at (a
transfer resumes from its ``.incoming/``).
"""

from __future__ import annotations

import logging
import os
import shutil
import time
from collections.abc import Collection
from pathlib import Path

from engine.wording import count

log = logging.getLogger("gaitrig.storage")

#: Age (s) after which a temporary file is a leftover.
STALE_S = 24 * 3600.0
_REPORT_UPLOAD = ".reference-upload-"
#: Pause after each recording's folder (see :data:`app.server.storage.RESCAN_PAUSE_S`).
PAUSE_S = 0.001


def _age_s(path: Path, now: float) -> float:
    try:
        return now - os.lstat(path).st_mtime
    except OSError:
        return -1.0


def _remove(path: Path, removed: list[Path]) -> None:
    try:
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        else:
            path.unlink()
    except OSError as exc:
        log.warning("could not remove the leftover %s: %s", path, exc)
        return
    removed.append(path)


def _is_part(path: Path) -> bool:
    """A node's part (a node id may end in .tmp): never cleaned here."""
    return path.is_dir() and any((path / n).exists() for n in (
        ".incoming", "manifest.json", "meta.json", "frames.bin"))


def _entries(folder: Path) -> list[os.DirEntry[str]]:
    try:
        with os.scandir(folder) as it:
            return list(it)
    except OSError:
        return []


def clean_stale(data_dir: Path, references: Collection[tuple[str, str]] | None = None,
                now: float | None = None) -> list[Path]:
    """Remove the leftovers of uploads and writes cut short (see the module docstring).

    Args:
        data_dir: the server's data folder.
        references: ``(recording id, stored name)`` of every ``reference_imports`` row;
            None leaves reference files without a row alone.
        now: the time to compare ages with (default: now).

    Returns:
        What was removed.
    """
    now = time.time() if now is None else now
    removed: list[Path] = []
    known = set(references) if references is not None else None
    for rec in _entries(Path(data_dir) / "references"):
        if not rec.is_dir(follow_symlinks=False):
            continue
        for e in _entries(Path(rec.path)):
            p = Path(e.path)
            if not e.is_file(follow_symlinks=False) or _age_s(p, now) <= STALE_S:
                continue
            if e.name.startswith(".") and e.name.endswith(".tmp"):
                _remove(p, removed)
            elif known is not None and (rec.name, e.name) not in known:
                _remove(p, removed)  # put in place, its row never committed
    for rec in _entries(Path(data_dir) / "recordings"):
        if not rec.is_dir(follow_symlinks=False):
            continue
        time.sleep(PAUSE_S)  # it runs beside the event loop: its requests come first
        for folder in (Path(rec.path), Path(rec.path) / "analysis"):
            for e in _entries(folder):
                p = Path(e.path)
                if not (e.name.startswith(".") and e.name.endswith(".tmp")) or _is_part(p):
                    continue
                if e.name.startswith(f"{_REPORT_UPLOAD}deleted-") or _age_s(p, now) > STALE_S:
                    _remove(p, removed)
    if removed:
        log.info("removed %s of uploads and writes cut short: %s", count(len(removed), "leftover"),
                 ", ".join(str(p.relative_to(data_dir)) for p in removed[:20]))
    return removed
