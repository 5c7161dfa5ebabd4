"""The check of a reference recording (C3D, TRC or skeleton CSV) being attached, shared by
the two places that attach one: the Subjects page (``POST /api/exports/{rec}/references``)
and the Reports page (``POST /api/reports/recordings/{rec}/reference``). The same file is
refused alike on both, with the same status and words:

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
from typing import Any

from fastapi import HTTPException, status

from app.api.routes._data import refusal
from app.server import analysis as an
from app.server import storage
from engine.errors import GaitrigError, InsufficientDataError
from engine.io.markers import MarkerTrajectories

#: What to do about a reference without a usable walk, on either page: neither takes
#: options for it (the Reports page's "Options for files from other labs" are "Analyse a
#: file"'s), so the fix is the file itself.
WHAT_TO_DO = ("Attach the reference recording of this walk: the motion-capture file of the "
              "same trial, with at least two steps and the ankle or heel markers named.")


def upload_name(filename: str | None) -> str:
    """The name of an uploaded file as the person chose it, for messages (no folders)."""
    return PurePath(filename or "reference").name[:255]


def check_reference(upload: Path, ext: str, name: str, attached: Sequence[str] = ()
                    ) -> tuple[MarkerTrajectories, list[dict[str, Any]]]:
    """Read the uploaded reference ``upload`` (a ``.{ext}`` file the person named
    ``name``) and find its steps as a report will; its trajectories and steps.

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
            traj = storage.read_reference(link, ext)
        except (GaitrigError, ValueError, OSError, RuntimeError) as exc:
            raise HTTPException(status.HTTP_400_BAD_REQUEST,
                                unreadable(exc, link, name, ext)) from exc
        try:
            steps = an.reference_steps(link)
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


def no_walk(exc: GaitrigError, copy: Path, name: str, attached: Sequence[str] = ()) -> str:
    """Why the reference ``name`` (read from ``copy``) was refused by the gait analysis,
    in a clinician's words: what is wrong, what to do, and that a reference ``attached``
    before stays ("'standing.trc' has no walk in it: 0 steps found — no straight walking
    (…). Attach the reference recording of this walk: …"). The engine's advice for
    recordings (place or add sensors) and for ``gaitrig gait`` (``--left/--right``,
    ``--up``, "give the units explicitly") is left out: it cannot be followed on either
    page."""
    why = refusal(exc, copy, name)
    if isinstance(exc, InsufficientDataError):
        # the reason, without the advice on recording that follows it
        found = why.split(". ", 1)[0].rstrip(".")
        if found.startswith("no straight walking found"):
            found = "0 steps found — no straight walking" + found.removeprefix(
                "no straight walking found")
        lead = f"{name!r} has no walk in it: {found}"
    else:  # no usable foot markers, a length unit or vertical axis not recognised, …
        kept = "; ".join(c for c in why.split("; ")
                         if "--" not in c and "give the units" not in c).rstrip(".")
        # (a reader's sentence that names the file is said as it is: named once)
        lead = kept if name in kept else f"{name!r} has no walk the report can use: {kept}"
    out = f"{lead}. {WHAT_TO_DO}"
    if len(attached) == 1:
        out += f" {attached[0]!r} stays attached."
    elif attached:
        out += f" The {len(attached)} references attached before stay."
    return out
