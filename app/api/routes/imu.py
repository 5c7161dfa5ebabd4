"""IMU page API: upload IMU files (and a depth skeleton), sync, fusion, plots, CSV.

``POST /api/imu/sessions`` (multipart) → a processed session: ``files`` (x-IMU CSV, Madgwick
``.mat``, BROAD ``.hdf5``/``.mat``, APDM ``.h5``, Xsens MVN ``.mvnx``, a phone app's
``.zip`` of one file per sensor, generic CSV with declared units), ``sensors`` (one name per
file, e.g. ``chest``, ``thigh_l``; default the file name), optional ``skeleton`` (skeleton
CSV, ``engine.io.csv``), ``filter`` (``ours`` | ``madgwick``), ``beta``, ``synchronise``,
``n_jumps`` and, for CSV, ``gyr_unit``, ``acc_unit``, ``mag_unit``, ``time_unit``
(``s``/``ms``/``us``/``ns``), ``frequency``: each overrides the unit in the file's header or
the one detected from the data (``engine.imu.io.load_csv``; what was assumed comes back in
the warnings). ``file_sensors`` picks the sensor to read from a CSV holding several (two
Shimmers, an Xsens export of several DOTs): one per file (empty for a one-sensor file) or
one for all; without it such a file is refused with the list of its sensors. Upload the file
twice, with two choices, to use two of its sensors. An ``.mvnx`` without a choice gives one
stream per tracker, named after its label (after ``<name>_`` when a name is given). A
``.zip`` (Sensor Logger, phyphox) is unpacked in memory-bounded steps (at most
``engine.imu._phone.MAX_ZIP_MEMBERS`` members and ``engine.imu._phone.MAX_ZIP_UNCOMPRESSED``
bytes unpacked, member names never used as paths). What one request reads — its zips
unpacked, its ``.mat``/HDF5 files at their numbers' size in memory (told from their
datasets' shapes, ``engine.imu.io.estimate_memory_bytes``), its CSVs (and skeleton CSV)
and ``.mvnx`` exports as they are — is at most ``MAX_REQUEST_DATA_BYTES`` together, else
413 before any file is read; each zip's directory is read once, for that bound and for its
unpacking (``engine.imu._phone.read_zip_directory``). ``platform``
(``ios``/``android``) declares its acceleration's sign convention when neither the phone's
orientation nor its metadata tells. ``quat_order`` (``wxyz``/``xyzw``) and ``quat_frame``
(``ENU``/``NED``) say how a CSV's reference quaternion columns are meant when gravity
cannot tell (they are then compared with the filter's orientation). Dropped samples are
filled on the nominal rate's grid (``engine.imu.io.fill_gaps``).

Instead of a skeleton file, ``recording`` and ``recording_node`` take one sensor's
skeleton from a recording already transferred to the server (placed in the world by the
recording's sensor pose); ``GET /api/imu/recordings`` lists them.

``POST /api/imu/simulate`` runs a simulated session (no hardware needed) with ground truth.
``GET /api/imu/sessions/{id}`` (summary), ``/plots/{name}.png`` and ``/data.csv``.
Results stay in server memory (last few sessions), never on disk.
"""

from __future__ import annotations

import contextlib
import re
import tempfile
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from fastapi import APIRouter, File, Form, HTTPException, Request, Response, UploadFile, status
from fastapi.concurrency import run_in_threadpool
from pydantic import BaseModel, Field

from app.api.deps import CurrentUser, HubDep, SettingsDep
from app.api.limits import BoundedRoute, size_words
from app.server.imu_analysis import (
    FilterName,
    ImuJob,
    ImuStore,
    fused_job,
    imu_only_job,
    simulated_job,
)
from engine.errors import InputError
from engine.imu._phone import ZipDirectory, load_phone, read_zip_directory
from engine.imu.fusion import PAPER_SENSORS
from engine.imu.io import (
    ImuRecording,
    MultipleSensorsError,
    estimate_memory_bytes,
    fill_gaps,
    load_imu,
    load_mvnx_all,
)
from engine.io.csv import read_skeleton_csv
from engine.skeleton import SkeletonSeries

router = APIRouter(prefix="/imu", route_class=BoundedRoute, tags=["imu"])

MAX_FILE_BYTES = 64 * 1024 * 1024
#: an MVNX export carries every segment's kinematics too (≈9 kB, 850 numbers, a frame for a
#: full suit: 64 MB is 2 min at 60 Hz); parsed frame by frame, only the sensor data kept
MAX_MVNX_BYTES = 256 * 1024 * 1024
MAX_FILES = 12
#: Whole multipart request: every IMU file, the skeleton file and the form fields.
MAX_REQUEST_BYTES = (MAX_FILES + 1) * MAX_FILE_BYTES + 1024 * 1024
_ALLOWED_SUFFIXES = (".csv", ".txt", ".tsv", ".mat", ".hdf5", ".h5", ".mvnx", ".zip")
#: data one request reads, every file together, one budget: phone zips unpacked, CSVs (the
#: skeleton's too) and ``.mvnx`` exports at their size, ``.mat``/HDF5 files at their
#: numbers' size in memory (at least the file's: a compressed dataset can unpack to far
#: more). Parsing peaks at ≈3.8× a zip's unpacked size in memory (256 MB → ≈1 GB), a CSV's
#: at ≈4× its numbers' (docs/file-formats.md), a .mat/HDF5 file's numbers are held whole,
#: and every file's recording is held until the session is built: 12 full zips would need
#: ≈12 GB, and 12 files of 64 MB were allowed beside them; one phone recording of this
#: size is over two hours of Sensor Logger at 100 Hz
MAX_REQUEST_DATA_BYTES = 256 * 2**20
#: files read as text, counted at their size against ``MAX_REQUEST_DATA_BYTES``
_TEXT_SUFFIXES = (".csv", ".txt", ".tsv")
#: streams of one session once MVNX exports are split per tracker (a full-body suit: 17)
MAX_STREAMS = 24
_NAME_RE = re.compile(r"^[A-Za-z0-9_\-]{1,40}$")
_ID_RE = re.compile(r"^[0-9a-f]{16}$")


def _store(request: Request) -> ImuStore:
    store: ImuStore | None = getattr(request.app.state, "imu_store", None)
    if store is None:
        store = ImuStore()
        request.app.state.imu_store = store
    return store


def _view(job: ImuJob) -> dict[str, Any]:
    base = f"/api/imu/sessions/{job.id}"
    return {"id": job.id, **job.summary,
            "plots": {n: f"{base}/plots/{n}.png" for n in job.plots},
            "csv_url": f"{base}/data.csv"}


async def _save(upload: UploadFile, folder: Path, stem: str) -> Path:
    """Copy an upload into ``folder`` under a safe name, at most ``MAX_FILE_BYTES``
    (``MAX_MVNX_BYTES`` for an MVNX export)."""
    name = upload.filename or ""
    suffix = Path(name).suffix.lower()
    if suffix not in _ALLOWED_SUFFIXES:
        raise HTTPException(status.HTTP_400_BAD_REQUEST,
                            f"{name or 'a file'}: unsupported type {suffix or '(none)'}; upload "
                            ".csv (x-IMU or generic), .mat (Madgwick or BROAD), .hdf5/.h5 "
                            "(BROAD or APDM), .mvnx (Xsens MVN) or .zip (a phone app's files)")
    path = folder / f"{stem}{suffix}"  # never the client's name: no path traversal
    limit = MAX_MVNX_BYTES if suffix == ".mvnx" else MAX_FILE_BYTES
    size = 0
    with path.open("wb") as fh:
        while chunk := await upload.read(1 << 20):
            size += len(chunk)
            if size > limit:
                raise HTTPException(status.HTTP_413_CONTENT_TOO_LARGE,
                                    f"{name}: larger than {size_words(limit)}; split "
                                    "the recording")
            fh.write(chunk)
    if size == 0:
        raise HTTPException(status.HTTP_400_BAD_REQUEST, f"{name}: the file is empty")
    return path


def _sensor_names(files: list[UploadFile], sensors: list[str],
                  choices: list[str] | None = None) -> list[str]:
    if sensors and len(sensors) != len(files):
        raise InputError(f"give one sensor name per file ({len(files)} files, "
                         f"{len(sensors)} names)")
    # default: the file name, and the sensor chosen in it (one file uploaded per sensor)
    stems = [Path(f.filename or "imu").stem + (f"_{c}" if c else "")
             for f, c in zip(files, choices or [""] * len(files), strict=True)]
    names = sensors or [re.sub(r"[^A-Za-z0-9_\-]", "_", s)[:40] or "imu" for s in stems]
    for n in names:
        if not _NAME_RE.match(n):
            raise InputError(f"sensor name {n!r}: use letters, digits, '_' or '-' (e.g. chest, "
                             "thigh_l)")
    if len(set(names)) != len(names):
        raise InputError(f"sensor names must differ; got {names}")
    return names


def _file_sensors(files: list[UploadFile], choices: list[str]) -> list[str]:
    """The sensor to read from each file ("" = the file's only one): one per file or one
    for all."""
    choices = [c.strip() for c in choices]
    for c in choices:
        if c and not _NAME_RE.match(c):
            raise InputError(f"sensor in file {c!r}: use the column prefix the file gives "
                             "its sensor (letters, digits, '_' or '-', e.g. Shimmer_8C4F)")
    if not any(choices):
        return [""] * len(files)
    if len(choices) == 1:
        return choices * len(files)
    if len(choices) != len(files):
        raise InputError(f"give one sensor-in-file choice per file or one for all "
                         f"({len(files)} files, {len(choices)} choices)")
    return choices


@router.post("/sessions", max_body_size=MAX_REQUEST_BYTES)
async def upload_session(
    request: Request,
    user: CurrentUser,
    settings: SettingsDep,
    hub: HubDep,
    files: Annotated[list[UploadFile], File(description="IMU recordings")],
    sensors: Annotated[list[str], Form()] = [],  # noqa: B006 - FastAPI form default
    skeleton: Annotated[UploadFile | None, File(description="depth skeleton CSV")] = None,
    filter: Annotated[Literal["ours", "madgwick"], Form()] = "ours",
    beta: Annotated[float, Form(gt=0, le=5)] = 0.041,
    synchronise: Annotated[bool, Form()] = True,
    n_jumps: Annotated[int, Form(ge=2, le=20)] = 5,
    gyr_unit: Annotated[str | None, Form()] = None,
    acc_unit: Annotated[str | None, Form()] = None,
    mag_unit: Annotated[str | None, Form()] = None,
    time_unit: Annotated[Literal["s", "ms", "us", "ns"] | None, Form()] = None,
    frequency: Annotated[float | None, Form(gt=0, le=10000)] = None,
    recording: Annotated[str | None, Form(max_length=64)] = None,
    recording_node: Annotated[str | None, Form(max_length=64)] = None,
    file_sensors: Annotated[list[str], Form()] = [],  # noqa: B006 - FastAPI form default
    quat_order: Annotated[Literal["wxyz", "xyzw"] | None, Form()] = None,
    quat_frame: Annotated[Literal["ENU", "NED"] | None, Form()] = None,
    platform: Annotated[Literal["ios", "android"] | None, Form()] = None,
) -> dict[str, Any]:
    """Process uploaded IMU files (and optionally a depth skeleton); see the module doc."""
    files = [f for f in files if f.filename]
    if not files:
        raise InputError("choose at least one IMU file")
    if len(files) > MAX_FILES:
        raise InputError(f"at most {MAX_FILES} IMU files per session")
    choices = _file_sensors(files, file_sensors)
    names = _sensor_names(files, [s.strip() for s in sensors if s.strip()], choices)
    kwargs: dict[str, Any] = {"time_unit": time_unit} if time_unit else {}
    if gyr_unit:
        kwargs["gyr_unit"] = gyr_unit
    if acc_unit:
        kwargs["acc_unit"] = acc_unit
    if mag_unit and mag_unit != "none":
        kwargs["mag_unit"] = mag_unit
    if frequency:
        kwargs["frequency"] = frequency
    if quat_order:
        kwargs["quat_order"] = quat_order
    if quat_frame:
        kwargs["quat_frame"] = quat_frame
    if platform:
        kwargs["platform"] = platform
    given = [s.strip() for s in sensors if s.strip()]
    filt: FilterName = filter
    with tempfile.TemporaryDirectory(prefix="gaitrig-imu-") as tmp:
        folder = Path(tmp)
        paths = [await _save(f, folder, f"imu{i}") for i, f in enumerate(files)]
        skel_path = None
        skel_name = skeleton.filename if skeleton is not None and skeleton.filename else ""
        if skeleton is not None and skeleton.filename:
            if Path(skeleton.filename).suffix.lower() != ".csv":
                raise InputError(f"{skeleton.filename}: the depth skeleton must be a skeleton "
                                 "CSV (time, SpineBase_x, ...)")
            skel_path = await _save(skeleton, folder, "skeleton")

        use_recording = bool(recording) and skel_path is None

        def work() -> ImuJob:
            with contextlib.ExitStack() as opened:
                return read_all(opened)

        def read_all(opened: contextlib.ExitStack) -> ImuJob:
            zips = _zip_directories(paths, opened)
            _check_request_data(paths, files, zips, skel_path, skel_name)
            recs: dict[str, ImuRecording] = {}
            for name, path, up, choice in zip(names, paths, files, choices, strict=True):
                try:
                    if path.suffix == ".mvnx" and not choice:  # one stream per tracker
                        for label, rec in load_mvnx_all(path).items():
                            stream = _tracker_name(name if given else "", label)
                            if stream in recs:
                                raise InputError(f"two streams named {stream!r}; give the "
                                                 "files different sensor names")
                            rec.name = stream
                            recs[stream] = fill_gaps(rec)
                        if len(recs) > MAX_STREAMS:
                            raise InputError(
                                f"{len(recs)} IMU streams (an MVNX export gives one per "
                                f"tracker); at most {MAX_STREAMS}: choose the trackers in "
                                "'Sensor in file' (form field file_sensors)")
                        continue
                    file_kw = {**kwargs, "sensor": choice} if choice else dict(kwargs)
                    if path in zips:  # its directory read once: for the bound, to unpack
                        zipped = zips[path]
                        if isinstance(zipped, Exception):  # said in the file's turn
                            raise zipped
                        file_kw["zip_directory"] = zipped
                    rec = _load(path, file_kw)
                except MultipleSensorsError as e:
                    msg = str(e).replace(path.name, up.filename or name).replace(
                        "with sensor", "in 'Sensor in file' (form field file_sensors)")
                    raise InputError(msg) from None
                except InputError as e:
                    # the engine names our temporary file; name the user's instead
                    msg = str(e).replace(path.name, up.filename or name).replace(
                        path.stem, Path(up.filename or name).stem).replace(str(folder) + "/", "")
                    if up.filename and up.filename not in msg:  # a zip's member was named
                        msg = f"{up.filename}: {msg}"
                    raise InputError(msg) from None
                except Exception as e:  # a damaged file can trip any reader library
                    raise InputError(f"{up.filename}: cannot read the file ({e}); check that it "
                                     "is a complete, unmodified export") from None
                if name in recs:
                    raise InputError(f"two streams named {name!r}; give the files different "
                                     "sensor names")
                rec.name = name
                recs[name] = rec
            if use_recording:
                sk_rec = recording_skeleton(settings.data_dir, recording or "",
                                            recording_node or "", _live_poses(hub))
                return _fuse_named(recs, sk_rec, filt, beta, n_jumps, synchronise)
            if skel_path is None:
                return imu_only_job(recs, filt=filt, beta=beta, n_jumps=n_jumps,
                                    synchronise=synchronise)
            try:
                sk = read_skeleton_csv(skel_path)
            except InputError as e:
                raise InputError(str(e).replace(str(skel_path), skel_name)
                                 .replace(skel_path.name, skel_name)) from None
            except Exception as e:  # damaged file
                raise InputError(f"{skel_name}: cannot read the skeleton CSV ({e})"
                                 ) from None
            return _fuse_named(recs, sk, filt, beta, n_jumps, synchronise)

        job = await run_in_threadpool(work)
    _store(request).add(job)
    return _view(job)


def _zip_directories(paths: list[Path], opened: contextlib.ExitStack
                     ) -> dict[Path, ZipDirectory | Exception]:
    """Each uploaded zip's directory, read once (closed with ``opened``); a zip that
    cannot be read keeps its error, raised when its turn comes (files are reported in
    order)."""
    out: dict[Path, ZipDirectory | Exception] = {}
    for path in paths:
        if path.suffix != ".zip":
            continue
        try:
            out[path] = opened.enter_context(read_zip_directory(path))
        except Exception as e:  # a damaged file can trip any reader library
            out[path] = e
    return out


def _check_request_data(paths: list[Path], files: list[UploadFile],
                        zips: dict[Path, ZipDirectory | Exception], skel_path: Path | None,
                        skel_name: str) -> None:
    """Refuse (413) a request whose files hold more than ``MAX_REQUEST_DATA_BYTES`` of
    data to read — phone zips unpacked (from their directories: each one alone is bounded
    by the engine), ``.mat``/HDF5 files at their numbers' size in memory (from their
    datasets' shapes: ``engine.imu.io.estimate_memory_bytes``), CSVs, the skeleton CSV and
    ``.mvnx`` exports at their size — before any is read."""
    sizes = [(up.filename or path.name, d.unpacked_bytes if isinstance(d, ZipDirectory)
              else 0) for path, up in zip(paths, files, strict=True)
             if (d := zips.get(path)) is not None]
    total = sum(n for _, n in sizes)
    limit = size_words(MAX_REQUEST_DATA_BYTES)
    if total > MAX_REQUEST_DATA_BYTES:
        mb = size_words(total, round_up=True)
        if len(sizes) == 1:
            msg = (f"{sizes[0][0]}: the zip unpacks to {mb}, more than the {limit} one "
                   "session may unpack; split the recording")
        else:
            name, largest = max(sizes, key=lambda s: s[1])
            msg = (f"the {len(sizes)} phone zips of this session unpack to {mb} together "
                   f"(the largest, {name}, to {size_words(largest)}), more than the "
                   f"{limit} one session may unpack; upload them in several sessions, "
                   "fewer zips each, or split the longest recording")
        raise HTTPException(status.HTTP_413_CONTENT_TOO_LARGE, msg)
    # the rest from their size or headers: CSVs and .mvnx at their size, .mat/HDF5 at
    # their numbers' size in memory (estimate_memory_bytes: at least the file's size)
    rest = [(up.filename or path.name, path.stat().st_size if path.suffix in _TEXT_SUFFIXES
             else estimate_memory_bytes(path))
            for path, up in zip(paths, files, strict=True) if path not in zips]
    if skel_path is not None:
        rest.append((skel_name or skel_path.name, skel_path.stat().st_size))
    sizes += rest
    total += sum(n for _, n in rest)
    if total <= MAX_REQUEST_DATA_BYTES:
        return
    name, largest = max(sizes, key=lambda s: s[1])
    held = (f"{name} holds" if len(sizes) == 1
            else f"the {len(sizes)} files of this session hold")
    of_largest = "" if len(sizes) == 1 else f"; the largest, {name}, {size_words(largest)}"
    raise HTTPException(
        status.HTTP_413_CONTENT_TOO_LARGE,
        f"upload fewer or shorter files: {held} {size_words(total, round_up=True)} to "
        "read (files as they are, phone zips unpacked, .mat and HDF5 files as their "
        f"numbers take in memory{of_largest}), at most {limit} in one session; upload "
        "them in several sessions or split the longest recording")


def _fuse_named(recs: dict[str, ImuRecording], sk: SkeletonSeries, filt: FilterName,
                beta: float, n_jumps: int, synchronise: bool) -> ImuJob:
    missing = [n for n in recs if n not in PAPER_SENSORS]
    if missing:
        raise InputError(f"to fuse with the depth skeleton name every sensor after its "
                         f"bone: {', '.join(PAPER_SENSORS)} (not {', '.join(missing)})")
    return fused_job(recs, sk, filt=filt, beta=beta, n_jumps=n_jumps, synchronise=synchronise)


def _live_poses(hub: Any) -> dict[str, Any]:
    return {s.id: s.sensor.T_world_sensor for s in hub.registry.nodes.values()
            if s.sensor.T_world_sensor is not None}


def recording_skeleton(data_dir: Path, rec_id: str, node: str,
                       live_poses: dict[str, Any]) -> SkeletonSeries:
    """One sensor's skeleton of a transferred recording, in the world frame (node clock).

    Raises:
        InputError: unknown recording or sensor, or no sensor pose.
    """
    from app.server import analysis as an

    rec_dir = an.recording_dir(data_dir, rec_id)
    parts = an.part_dirs(rec_dir)
    if not parts:
        raise InputError(f"recording {rec_id!r} has no sensor data on the server; transfer it "
                         "from the nodes first (Subjects & recordings)")
    if node not in parts:
        raise InputError(f"recording {rec_id} has no part from sensor {node!r}; it has "
                         f"{', '.join(parts)}")
    poses = an.sensor_poses(rec_dir, live_poses)
    if node not in poses:
        raise InputError(f"sensor {node} of recording {rec_id} has no pose; calibrate the rig "
                         "so its skeleton can be placed in the world")
    T = np.asarray(poses[node]["T_world_sensor"], dtype=float)
    s = an.read_part(parts[node])
    P = s.positions @ T[:3, :3].T + T[:3, 3]
    return SkeletonSeries(s.times, P, s.states, s.joint_set, {"recording": rec_id,
                                                              "sensor_id": node})


@router.get("/recordings")
async def recordings(user: CurrentUser, settings: SettingsDep) -> list[dict[str, Any]]:
    """Recordings on the server with skeleton parts (depth source for the fusion)."""
    from app.server import analysis as an

    root = Path(settings.data_dir) / an.RECORDINGS_DIR
    out = []
    if root.is_dir():
        for d in sorted((p for p in root.iterdir() if p.is_dir()), reverse=True)[:200]:
            parts = an.part_dirs(d)
            if parts:
                out.append({"id": d.name, "sensors": sorted(parts)})
    return out


def _tracker_name(prefix: str, label: str) -> str:
    """A stream name for an MVNX tracker (``Pelvis``, ``chest_Pelvis``) the form accepts."""
    name = re.sub(r"[^A-Za-z0-9_\-]", "_", f"{prefix}_{label}" if prefix else label)[:40]
    return name or "tracker"


def _load(path: Path, kwargs: dict[str, Any]) -> ImuRecording:
    # dropped samples filled: the filters assume a constant rate (engine.imu.io.fill_gaps)
    if path.suffix in _TEXT_SUFFIXES:
        return fill_gaps(load_imu(path, **{k: v for k, v in kwargs.items()
                                           if k != "platform"}))
    if path.suffix == ".zip":  # its directory already read (_zip_directories)
        return fill_gaps(load_phone(kwargs.get("zip_directory") or path,
                                    platform=kwargs.get("platform")))
    if path.suffix == ".mvnx":
        return fill_gaps(load_imu(path, sensor=kwargs.get("sensor")))
    if path.suffix in (".h5", ".hdf5"):  # APDM: one sensor of several, its reference frame
        return fill_gaps(load_imu(path, **{k: v for k, v in kwargs.items()
                                           if k in ("sensor", "quat_frame")}))
    return fill_gaps(load_imu(path))


class SimulateIn(BaseModel):
    """Options of a simulated session."""

    filter: Literal["ours", "madgwick"] = "ours"
    beta: float = Field(default=0.041, gt=0, le=5)
    seed: int = Field(default=0, ge=0, le=10_000)


@router.post("/simulate")
async def simulate(request: Request, user: CurrentUser, body: SimulateIn) -> dict[str, Any]:
    """A whole simulated session (plank, jumps, walking) with ground-truth RMSE."""
    job = await run_in_threadpool(simulated_job, body.seed, body.filter, body.beta)
    _store(request).add(job)
    return _view(job)


def _job(request: Request, job_id: str) -> ImuJob:
    job = _store(request).get(job_id) if _ID_RE.match(job_id) else None
    if job is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            "no such IMU session (results are kept for the last few sessions "
                            "only); upload the files again")
    return job


@router.get("/sessions/{job_id}")
async def get_session(request: Request, job_id: str, user: CurrentUser) -> dict[str, Any]:
    """Summary of a processed session."""
    return _view(_job(request, job_id))


@router.get("/sessions/{job_id}/plots/{name}.png")
async def get_plot(request: Request, job_id: str, name: str, user: CurrentUser) -> Response:
    """One plot (``sync``, ``angles`` or ``orientation``) as PNG."""
    job = _job(request, job_id)
    if name not in job.plots:
        raise HTTPException(status.HTTP_404_NOT_FOUND,
                            f"no {name!r} plot; this session has {sorted(job.plots)}")
    return Response(job.plots[name], media_type="image/png",
                    headers={"Cache-Control": "no-store"})


@router.get("/sessions/{job_id}/data.csv")
async def get_csv(request: Request, job_id: str, user: CurrentUser) -> Response:
    """Joint angles (fused and depth) or orientations as CSV."""
    job = _job(request, job_id)
    return Response(job.csv_text, media_type="text/csv",
                    headers={"Content-Disposition": f'attachment; filename="{job.csv_name}"',
                             "Cache-Control": "no-store"})
