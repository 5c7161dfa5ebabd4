"""Subject exports under way, so that a deletion never cuts one short.

An export streams the subject's files for as long as the download takes. A deletion
of the subject (or of one of its sessions or recordings, or of its project) started
meanwhile is refused (409) until the download ends; an export asked for while such a
deletion runs is refused likewise. Simpler than exporting from a snapshot, which would
keep a deleted subject's data on the server for as long as a download lasts.
"""

from __future__ import annotations

import threading
from collections import Counter
from collections.abc import Callable, Iterable
from pathlib import Path

from fastapi import HTTPException, status

Release = Callable[[], None]


class ExportGuard:
    """Which subjects are being exported or deleted (thread-safe: exports start in the
    thread pool, deletions in the event loop)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._exporting: Counter[tuple[str, int]] = Counter()
        self._deleting: Counter[tuple[str, int]] = Counter()

    @staticmethod
    def _keys(data_dir: Path, subject_ids: Iterable[int]) -> list[tuple[str, int]]:
        root = str(Path(data_dir).resolve())
        return sorted({(root, int(s)) for s in subject_ids})

    def start_export(self, data_dir: Path, subject_id: int) -> Release:
        """Claim a subject for an export (call before reading it from the database).

        Returns:
            The release, to call once when the download has ended (idempotent).

        Raises:
            HTTPException: 409 while the subject, or part of it, is being deleted.
        """
        keys = self._keys(data_dir, [subject_id])
        with self._lock:
            if any(self._deleting[k] for k in keys):
                raise HTTPException(status.HTTP_409_CONFLICT,
                                    f"subject {subject_id} (or part of it) is being deleted; "
                                    "reload the Subjects page")
            self._exporting.update(keys)
        return self._releaser(self._exporting, keys)

    def start_deletion(self, data_dir: Path, subject_ids: Iterable[int]) -> Release:
        """Claim subjects for a deletion of theirs.

        Raises:
            HTTPException: 409 while an export of one of them is being downloaded.
        """
        keys = self._keys(data_dir, subject_ids)
        with self._lock:
            busy = [k[1] for k in keys if self._exporting[k]]
            if busy:
                raise HTTPException(status.HTTP_409_CONFLICT,
                                    f"subject {busy[0]}'s export is being downloaded; delete "
                                    "when the download has ended (or was cancelled)")
            self._deleting.update(keys)
        return self._releaser(self._deleting, keys)

    def _releaser(self, counts: Counter[tuple[str, int]], keys: list[tuple[str, int]]
                  ) -> Release:
        done = False

        def release() -> None:
            nonlocal done
            with self._lock:
                if done:
                    return
                done = True
                counts.subtract(keys)
                for k in keys:
                    if counts[k] <= 0:
                        del counts[k]

        return release


#: The server's guard (keys hold the data folder, so servers in one process are apart).
EXPORTS = ExportGuard()
