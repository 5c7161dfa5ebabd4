"""The check of a reference recording (C3D, TRC or skeleton CSV) being attached, shared by
the two places that attach one: the Subjects page (``POST /api/exports/{rec}/references``)
and the Reports page (``POST /api/reports/recordings/{rec}/reference``). The same file is
refused alike on both, with the same status and words:

* 400 — not a ``.c3d``, ``.trc`` or ``.csv`` file (:func:`reference_type`), or an empty
  one (:func:`receive`): "'walk.pdf': choose a .c3d, .trc or skeleton .csv file", "'trial
  3.c3d' is empty …";
* 413 — larger than :data:`MAX_REFERENCE_BYTES`: "'trial 3.c3d' is larger than 200 MB,
  the largest file the server takes: …" (:func:`too_large`), whether :func:`receive` counts
  the file or the route's ``max_body_size`` (that and :data:`UPLOAD_OVERHEAD`) refuses the
  request before the file is known ("The file is larger than 200 MB, …");
* 400 — no reader takes it: "'trial 3.c3d' is not a readable C3D file: the file is
  damaged …" (a reader's sentence that names the file is said as it is);
* 422 — it is read, and the report's gait analysis
  (:func:`app.server.analysis.reference_steps`) finds no usable walk in it: "'standing.trc'
  has no walk in it: 0 steps found — no straight walking (…). Attach the reference
  recording of this walk: …", naming the reference attached before, which stays.

Both run in a worker thread: the caller's ``asyncio.to_thread``."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Sequence
from pathlib import Path, PurePath
from typing import Any, BinaryIO

from fastapi import HTTPException, UploadFile, status

from app.api.limits import size_words
from app.api.routes._data import refusal
from app.db.data import REFERENCE_FORMATS
from app.server import analysis as an
from app.server import storage
from engine.errors import GaitrigError, InsufficientDataError
from engine.io.markers import MarkerTrajectories

#: What to do about a reference without a usable walk, on either page: neither takes
#: options for it (the Reports page's "Options for files from other labs" are "Analyse a
#: file"'s), so the fix is the file itself.
WHAT_TO_DO = ("Attach the reference recording of this walk: the motion-capture file of the "
              "same trial, with at least two steps and the ankle or heel markers named.")


#: Largest reference file either page takes (a C3D of a long Vicon session with analog
#: data is ~100 MB); also the Reports page's "Analyse a file", which takes the same files.
MAX_REFERENCE_BYTES = 200 * 1024 * 1024
#: What a multipart request adds to the file it carries: a route taking one file accepts
#: a body of ``MAX_REFERENCE_BYTES + UPLOAD_OVERHEAD``.
UPLOAD_OVERHEAD = 64 * 1024
_CHUNK = 1024 * 1024


def upload_name(filename: str | None) -> str:
    """The name of an uploaded file as the person chose it, for messages (no folders)."""
    return PurePath(filename or "reference").name[:255]


def reference_type(name: str) -> str:
    """The format (``"c3d"``, ``"trc"`` or ``"csv"``) of an upload the person named
    ``name``, told by its extension.

    Raises:
        HTTPException: 400 for any other extension.
    """
    ext = name.rsplit(".", 1)[-1].lower() if "." in name else ""
    if ext not in REFERENCE_FORMATS:
        raise HTTPException(status.HTTP_400_BAD_REQUEST,
                            f"{name!r}: choose a .c3d, .trc or skeleton .csv file")
    return ext


async def receive(file: UploadFile, out: BinaryIO, name: str) -> int:
    """Copy the upload ``file`` (named ``name`` by the person) into ``out``, within
    :data:`MAX_REFERENCE_BYTES`; the number of bytes copied.

    Raises:
        HTTPException: 413 when it is larger (nothing more is read), 400 when it is empty.
    """
    limit = MAX_REFERENCE_BYTES
    size = 0
    while chunk := await file.read(_CHUNK):
        size += len(chunk)
        if size > limit:
            raise too_large(name)
        out.write(chunk)
    if size == 0:
        raise HTTPException(status.HTTP_400_BAD_REQUEST,
                            f"{name!r} is empty: choose the file again, or export it again "
                            "from the motion-capture software")
    return size


def too_large(name: str | None = None) -> HTTPException:
    """HTTP 413 for a file larger than :data:`MAX_REFERENCE_BYTES`, named ``name`` (None:
    a request refused by its size before the file's name is read), on every route that
    takes a reference-sized file: the same words whichever check finds it ("'trial 3.c3d'
    is larger than 200 MB, the largest file the server takes: export only the walk …")."""
    who = repr(name) if name else "The file"
    return HTTPException(status.HTTP_413_CONTENT_TOO_LARGE,
                         f"{who} is larger than {size_words(MAX_REFERENCE_BYTES)}, the "
                         "largest file the server takes: export only the walk (without "
                         "analog channels) from the motion-capture software and upload it")


def check_reference(upload: Path, ext: str, name: str, attached: Sequence[str] = ()
                    ) -> tuple[MarkerTrajectories, list[dict[str, Any]]]:
    """Read the uploaded reference ``upload`` (a ``.{ext}`` file the person named
    ``name``) and find its steps as a report will; its trajectories and steps. The file
    is parsed once (:func:`app.server.storage.parse_reference`): the analysis takes what
    was read (it read the file again: ≈ 2 s more for a 200 MB C3D).

    The readers and the analysis tell the format by the file's extension, and name the
    file in their messages: they read it through a link named ``reference.{ext}`` in a
    private temporary folder (outside the data folder: nothing for a backup to take), and
    the messages say ``name`` instead.

    Raises:
        HTTPException: 400 when no reader takes the file, 422 when the analysis finds no
            usable walk in it (:func:`no_walk`; ``attached`` are the names of the
            references attached before in the same place, which stay).
    """
    with tempfile.TemporaryDirectory(prefix="gaitrig-reference-check-") as d:
        link = Path(d) / f"reference.{ext}"
        os.symlink(upload.resolve(), link)
        try:
            data = storage.parse_reference(link, ext)
            traj = storage.reference_markers(data)  # what is stored of it
        except (GaitrigError, ValueError, OSError, RuntimeError) as exc:
            raise HTTPException(status.HTTP_400_BAD_REQUEST,
                                unreadable(exc, link, name, ext)) from exc
        try:
            steps = an.reference_steps(link, data=data)
        except GaitrigError as exc:
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                                no_walk(exc, link, name, attached)) from exc
    return traj, steps


def unreadable(exc: BaseException, copy: Path, name: str, ext: str) -> str:
    """Why no reader takes the reference ``name`` (read from ``copy``), naming it once: a
    reader's "cannot read walk.c3d as C3D: …" or "Gang.trc is not a TRC file …" says what
    a prefix would say first."""
    why = refusal(exc, copy, name)
    return why if name in why else f"{name!r} is not a readable {ext.upper()} file: {why}"


#: How an option the analysis names is said where no option can be given (the person
#: gave none: an engine error names one only in its advice, which is left out here).
OPTION_NAMES = {"up": "the vertical axis", "units": "the units",
                "markers": "the left and right foot markers",
                "ankle_markers": "the ankle markers", "ankle_width_mm": "the ankle width"}


def _name_option(option: str, value: str | None, verb: str, example: str | None) -> str:
    """An option named in an error's reason (:meth:`GaitrigError.words`), said plainly."""
    return OPTION_NAMES[option] + (f" {value}" if value else "")


def no_walk(exc: GaitrigError, copy: Path, name: str, attached: Sequence[str] = ()) -> str:
    """Why the reference ``name`` (read from ``copy``) was refused by the gait analysis,
    in a clinician's words: what is wrong, what to do, and that a reference ``attached``
    before stays ("'standing.trc' has no walk in it: 0 steps found — no straight walking
    (…). Attach the reference recording of this walk: …"). The engine's advice for
    recordings (place or add sensors) and for ``gaitrig gait`` (``--left/--right``,
    ``--up``, "give the units explicitly") is left out: it cannot be followed on either
    page. The error's :attr:`~engine.errors.GaitrigError.reason` says what is wrong; an
    error raised with its message only (which names no option) is said as it is."""
    reason = (exc.words(_name_option, advice=False) or "") if exc.structured else None
    why = refusal(exc, copy, name, reason).rstrip(".")
    if isinstance(exc, InsufficientDataError):
        found = why  # the reason, without the advice on recording that follows it
        if found.startswith("no straight walking found"):
            found = "0 steps found — no straight walking" + found.removeprefix(
                "no straight walking found")
        lead = f"{name!r} has no walk in it: {found}"
    else:  # no usable foot markers, a length unit or vertical axis not recognised, …
        # (a reader's sentence that names the file is said as it is: named once)
        lead = (why if name in why else f"{name!r} has no walk the report can use"
                + (f": {why}" if why else ""))
    out = f"{lead}. {WHAT_TO_DO}"
    if len(attached) == 1:
        out += f" {attached[0]!r} stays attached."
    elif attached:
        out += f" The {len(attached)} references attached before stay."
    return out
