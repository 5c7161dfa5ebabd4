"""Subject exports under way, so that a deletion never cuts one short.

An export streams the subject's files for as long as the download takes. A deletion
of the subject (or of one of its sessions or recordings, or of its project) started
meanwhile is refused (409) until the download ends; an export asked for while such a
deletion runs is refused likewise. Simpler than exporting from a snapshot, which would
keep a deleted subject's data on the server for as long as a download lasts.

Each app holds its own guard (``app.state.exports``, made by
:func:`app.main.create_app`; routes reach it through :data:`app.api.deps.ExportsDep`),
so two apps in one process never share one.
"""

from __future__ import annotations

import threading
from collections import Counter
from collections.abc import Callable, Iterable

from fastapi import HTTPException, status

Release = Callable[[], None]


class ExportGuard:
    """Which subjects of one app's database are being exported or deleted (thread-safe:
    exports start in the thread pool, deletions in the event loop)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._exporting: Counter[int] = Counter()
        self._deleting: Counter[int] = Counter()

    @property
    def exporting(self) -> set[int]:
        """The subjects whose export is being downloaded now."""
        with self._lock:
            return set(self._exporting)

    def start_export(self, subject_id: int) -> Release:
        """Claim a subject for an export (call before reading it from the database).

        Returns:
            The release, to call once when the download has ended (idempotent).

        Raises:
            HTTPException: 409 while the subject, or part of it, is being deleted.
        """
        keys = [int(subject_id)]
        with self._lock:
            if any(self._deleting[k] for k in keys):
                raise HTTPException(status.HTTP_409_CONFLICT,
                                    f"subject {subject_id} (or part of it) is being deleted; "
                                    "reload the Subjects page")
            self._exporting.update(keys)
        return self._releaser(self._exporting, keys)

    def start_deletion(self, subject_ids: Iterable[int]) -> Release:
        """Claim subjects for a deletion of theirs.

        Raises:
            HTTPException: 409 while an export of one of them is being downloaded.
        """
        keys = sorted({int(s) for s in subject_ids})
        with self._lock:
            busy = [k for k in keys if self._exporting[k]]
            if busy:
                raise HTTPException(status.HTTP_409_CONFLICT,
                                    f"subject {busy[0]}'s export is being downloaded; delete "
                                    "when the download has ended (or was cancelled)")
            self._deleting.update(keys)
        return self._releaser(self._deleting, keys)

    def _releaser(self, counts: Counter[int], keys: list[int]) -> Release:
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
