"""``<data_dir>/recordings.json``: the backbone's recordings, appended to in place.

A server keeps every recording it ever made (tens of thousands after years in a clinic)
and a recording's state changes many times (start, stop, each part, each transfer).
Rewriting the whole list on every change cost close to a second of the event loop at
clinic size, so the file is a JSON list with one recording per line that a change
*appends to*::

    [{"format": "gaitrig recordings: one per line; a later line replaces ..."}
    ,{"id": "R20261122-101500-ab12", "t_start": ..., "parts": {...}}
    ,{"id": "R20261122-101500-ab12", "t_start": ..., "parts": {...}}
    ]

A change writes ``,<recording>\\n]\\n`` over the closing ``]\\n`` (one write, synced): the
lines before it are never touched, so a crash in the middle of a write can lose only that
change. The file stays one JSON list (a later element replaces an earlier one with the
same ``id``; the first element, without an ``id``, names the format), which is what a
backup reads (:func:`app.server.backup._live_entries`). Loading keeps every complete line
before a torn one and rewrites the file. The file is rewritten whole (written to
``recordings.tmp``, synced, renamed) only when that is needed: a removed recording (its
id must leave the disk), a torn or older file at start, or when replaced lines make up
more than half of it (so its size stays bounded by twice the recordings; amortised, a
change costs one line).
"""

from __future__ import annotations

import json
import logging
import os
import threading
from collections.abc import Iterable
from pathlib import Path
from typing import Any

log = logging.getLogger("gaitrig.recording")

HEADER = (b'[{"format": "gaitrig recordings: one per line; a later line replaces an earlier '
          b'one of the same id"}\n')
CLOSE = b"]\n"
#: Replaced lines tolerated before a rewrite, besides one per recording.
SLACK_LINES = 1000


def fsync_dir(folder: Path) -> None:
    """Make a rename in ``folder`` durable (POSIX; a no-op where folders cannot be opened)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


class RecordingFile:
    """The lines of ``recordings.json`` (see the module docstring).

    Keeps each recording's last written line in memory, so that a rewrite serialises
    nothing again.

    Args:
        path: the file (``<data_dir>/recordings.json``).
    """

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.tmp = self.path.with_suffix(".tmp")
        self._lines: dict[str, bytes] = {}  # id -> its JSON (no comma, no newline)
        self._end: int | None = None  # offset of the closing "]" (None: rewrite first)
        self._n_lines = 0  # recording lines in the file (replaced ones included)
        self._lock = threading.Lock()  # one writer at a time (deletions run in threads)

    # ------------------------------------------------------------------ reading

    def load(self) -> list[dict[str, Any]]:
        """Every recording in the file, the last line of each id; a file in the older
        whole-list format, or with a torn last write, is rewritten in this format.

        Raises:
            OSError: the file exists but cannot be read.
            ValueError: it is neither format (nothing was kept from it).
        """
        with self._lock:
            self._lines, self._end, self._n_lines = {}, None, 0
            if not self.path.exists():
                return []
            data = self.path.read_bytes()
            fast = self._parse_whole(data) if data.startswith(HEADER) else None
            if fast is not None:
                recs, complete = fast, True
            elif data.startswith(HEADER):
                recs, complete = self._parse_lines(data)
            else:  # a list written whole by an older server (or a test)
                raw = json.loads(data)
                if not isinstance(raw, list):
                    raise ValueError("not a JSON list")
                recs = [r for r in raw if isinstance(r, dict) and "id" in r]
                for r in recs:
                    self._lines[str(r["id"])] = json.dumps(r, separators=(",", ":")).encode()
                complete = False
            if complete:
                self._end = len(data) - len(CLOSE)
            else:
                log.warning("%s: rewriting it (%d recordings kept)%s", self.path, len(self._lines),
                            "" if not data.startswith(HEADER) else
                            "; its last write was cut short (a crash or a full disk)")
                try:
                    self._rewrite()
                except OSError as exc:  # read-only for now: appended to once it can be
                    log.error("cannot rewrite %s: %s", self.path, exc)
            by_id = {str(r["id"]): r for r in recs}
            return list(by_id.values())

    def _parse_whole(self, data: bytes) -> list[dict[str, Any]] | None:
        """The recordings of a whole file in this format, parsed at once (a third faster
        than line by line); None when it is not whole (then read line by line)."""
        if not data.endswith(b"\n" + CLOSE):
            return None
        try:
            raw = json.loads(data)
        except ValueError:
            return None
        lines = data[len(HEADER):-len(CLOSE) - 1].split(b"\n") if len(raw) > 1 else []
        if not isinstance(raw, list) or len(lines) != len(raw) - 1:
            return None
        recs = raw[1:]
        for ln, r in zip(lines, recs, strict=True):
            if not isinstance(r, dict) or "id" not in r or not ln.startswith(b","):
                self._lines = {}
                return None
            self._lines[str(r["id"])] = ln[1:]
        self._n_lines = len(recs)
        return recs

    def _parse_lines(self, data: bytes) -> tuple[list[dict[str, Any]], bool]:
        """The recordings of a file in this format, and whether it ended as written."""
        recs: list[dict[str, Any]] = []
        lines = data[len(HEADER):].split(b"\n")
        for i, ln in enumerate(lines):
            if ln == b"]":
                self._n_lines = i
                return recs, lines[i + 1:] == [b""]
            if not ln.startswith(b","):
                break
            try:
                r = json.loads(ln[1:])
            except ValueError:
                break  # torn: everything before it stays
            if not isinstance(r, dict) or "id" not in r:
                break
            recs.append(r)
            self._lines[str(r["id"])] = ln[1:]
        self._n_lines = len(recs)
        return recs, False

    # ------------------------------------------------------------------ writing

    def line(self, rec_id: str) -> bytes | None:
        """The recording's JSON as last written (None: not in the file)."""
        return self._lines.get(rec_id)

    def write(self, changed: dict[str, bytes], removed: Iterable[str] = ()) -> None:
        """Put the ``changed`` recordings' lines (id -> JSON, as :meth:`line` gives) and
        drop the ``removed`` ones: appended, or the file rewritten when needed.

        Raises:
            OSError: the file could not be written (what it held before is intact).
        """
        with self._lock:
            gone = [k for k in removed if k in self._lines]
            new = {k: v for k, v in changed.items() if self._lines.get(k) != v}
            if not gone and not new:
                return
            if (gone or self._end is None
                    or self._n_lines + len(new) > 2 * len(self._lines) + SLACK_LINES):
                old = dict(self._lines)
                for k in gone:
                    self._lines.pop(k, None)
                self._lines.update(new)
                try:
                    self._rewrite()
                except OSError:
                    self._lines = old
                    raise
                return
            body = b"".join(b"," + v + b"\n" for v in new.values())
            try:
                with open(self.path, "r+b") as fh:
                    fh.seek(self._end)
                    fh.write(body + CLOSE)
                    fh.truncate()  # what a failed write may have left after it
                    fh.flush()
                    os.fsync(fh.fileno())
            except OSError:
                self._end = None  # (the file may be gone): the next write rewrites it
                raise
            self._end += len(body)
            self._n_lines += len(new)
            self._lines.update(new)

    def _rewrite(self) -> None:
        """Write every recording's line once (temporary file, synced, renamed)."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        body = b"".join(b"," + v + b"\n" for v in self._lines.values())
        try:
            with open(self.tmp, "wb") as fh:
                fh.write(HEADER + body + CLOSE)
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(self.tmp, self.path)
        except OSError:
            self._end = None  # the next write rewrites again
            raise
        fsync_dir(self.path.parent)
        self._end = len(HEADER) + len(body)
        self._n_lines = len(self._lines)
