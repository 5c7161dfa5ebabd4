"""Wire protocol between node agents and the server (websocket, version 1).

Two kinds of websocket messages:

* **Control** — UTF-8 JSON text objects ``{"v": 1, "type": ..., ...}`` validated by the
  pydantic models below (:data:`NodeMessage` node→server, :data:`ServerMessage`
  server→node). Bounded by ``Settings.max_control_bytes``.
* **Bulk** — binary messages: ``b"GRB" + version byte``, a little-endian ``uint32``
  header length, a JSON header (``kind`` = ``skeleton`` | ``image`` | ``manifest`` |
  ``chunk``, ``seq``, ``t`` = node-local capture time in seconds, ...) and a raw payload.
  Skeleton payloads are ``float32 (B, J, 3)`` positions in metres in the sensor frame
  followed by ``uint8 (B, J)`` tracking states; image payloads are PNG/JPEG bytes;
  ``manifest``, ``chunk`` and ``channel`` carry a recording part's transfer
  (:mod:`app.transfer`; the chunk bytes normally take a raw TCP data channel offered by
  ``data_channel``, the websocket ``chunk`` messages are its fallback);
  ``calib`` carries one colour + depth frame of a calibration capture with the camera model
  (:func:`encode_calib_frame`).
  Bounded by ``Settings.max_binary_bytes``.

Time: every node timestamp on the wire is in the node's **local** clock. The server
estimates each node's offset (``t_local - t_server``) from ``ping``/``pong`` four-timestamp
exchanges and converts; recording commands carry both the server time and the server's
conversion into the node's local time, so nodes never need to know the offset.

Session: the node opens ``/ws/node`` and sends ``hello`` (id, token, protocol version,
sensor description, parts it holds: as many as :data:`PART_LIST_BYTES` allow, the rest in
``parts`` messages right after the welcome). The server answers ``welcome`` or ``refused``
(with a reason, then closes with code 4401/4400). Afterwards the server sends ``ping`` every
~0.1 s, ``rec_start``/``rec_stop`` for synchronous recordings, ``subscribe`` for image
streams at N fps, ``snapshot`` for a one-off image set; the node streams skeleton frames,
``status`` once per second, ``rec_state`` when a recording part changes, ``warning`` when
its sensor backend runs into a problem (revision 2, only to a server whose welcome accepts
it: :data:`PROTOCOL_REVISION`), ``sensor_lens`` once right after the welcome with its
cameras' intrinsics and lens distortion (revision 3, likewise), and answers malformed
input with ``error`` (never by closing).
"""

from __future__ import annotations

import json
import struct
import unicodedata
from collections.abc import Sequence
from typing import Annotated, Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError, field_validator

from engine.errors import InputError

PROTOCOL_VERSION = 1
#: Revision of version 1 a node speaks, sent as ``hello.protocol`` (which servers before it
#: never checked): 2 adds the node's ``warning`` messages, 3 its ``sensor_lens``. A server
#: answers a node of revision 2 or later with ``welcome.accepts`` naming the optional
#: messages it takes (so its revision: ``sensor_lens`` from 3 on); an older node gets the
#: welcome it knows (its parser refuses unknown fields) and ignores names it does not
#: know, and a node sends an optional message only to a server whose welcome accepts it
#: (an older one would answer each with ``error``; its hello cannot carry them either, an
#: older server refuses unknown hello fields).
PROTOCOL_REVISION = 3
BINARY_MAGIC = b"GRB" + bytes([PROTOCOL_VERSION])
_HDR = struct.Struct("<4sI")
MAX_BINARY_HEADER = 16 * 1024
BINARY_KINDS = ("skeleton", "image", "manifest", "chunk", "deleted", "calib", "channel")

StreamName = Literal["depth", "color", "body_index"]
RecId = Annotated[str, Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")]
PartState = Literal["pending", "recording", "on_node", "incomplete"]


class ProtocolError(InputError):
    """A websocket message that does not follow this protocol (reason in the message)."""


class _Msg(BaseModel):
    model_config = ConfigDict(extra="forbid")
    v: Literal[1] = 1


# --------------------------------------------------------------------------- node → server


class SensorInfo(BaseModel):
    """What a node's sensor is: model, image sizes, intrinsics, nominal rate, pose if known."""

    model_config = ConfigDict(extra="forbid")
    model: str = "unknown"
    depth_size: tuple[int, int] = (512, 424)
    color_size: tuple[int, int] = (1920, 1080)
    depth_K: list[list[float]] | None = None  # noqa: N815 - matrix name
    color_K: list[list[float]] | None = None  # noqa: N815
    fov_deg: tuple[float, float] = (70.6, 60.0)
    rate_hz: float = 30.0
    joint_set: str = "kinect_v2"
    T_world_sensor: list[list[float]] | None = Field(
        default=None, description="Known pose (the simulator's truth); calibration replaces it."
    )
    warnings: list[Annotated[str, Field(max_length=2000)]] = Field(
        default_factory=list, max_length=8,
        description="Problems of the node's sensor setup (e.g. no body-tracking SDK), "
                    "shown with the node's health.")


#: Characters of a part's ``reason`` in a listing: a longer one is cut with an ellipsis (a
#: reason grows by one clause per reopening or failure, and one part over the listing's
#: bound would get the node's hello refused for good).
PART_REASON_CHARS = 500


def _cut(v: Any, chars: int) -> Any:
    """``v`` cut to ``chars`` characters ending in "…" if it is a longer string, else as is."""
    if isinstance(v, str) and len(v) > chars:
        return v[:chars - 1] + "…"
    return v


class PartInfo(BaseModel):
    """A recording part as held by a node (times in the node's local clock).

    Every field is bounded so one part never outgrows a listing message
    (:func:`part_batches`): ``rec_id`` is a recording id (1-64 of ``A-Za-z0-9_.-``) and a
    ``reason`` longer than :data:`PART_REASON_CHARS` is cut to that with an ellipsis.
    """

    model_config = ConfigDict(extra="forbid")
    rec_id: RecId
    state: PartState
    n_frames: int = 0
    t_first: float | None = None
    t_last: float | None = None
    bytes: int = 0
    reason: Annotated[str, Field(max_length=PART_REASON_CHARS)] | None = None

    @field_validator("reason", mode="before")
    @classmethod
    def _cut_reason(cls, v: Any) -> Any:
        # cut rather than refuse: the reason is for a person, the part must still be listed
        return _cut(v, PART_REASON_CHARS)


class Hello(_Msg):
    type: Literal["hello"] = "hello"
    node_id: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")
    token: str = Field(max_length=256)
    protocol: int = Field(default=PROTOCOL_REVISION,
                          description="Revision of version 1 (PROTOCOL_REVISION).")
    backend: str = "unknown"
    agent_started: float = Field(default=0.0, description="Node-local start of the agent.")
    sensor: SensorInfo = Field(default_factory=lambda: SensorInfo())
    parts: list[PartInfo] = Field(default_factory=list, max_length=10000)


#: Bytes of part listings in one control message (``hello`` or ``parts``): well under the
#: server's limit on a control message (``Settings.max_control_bytes``, 64 KiB), which the
#: node does not know before its hello is answered.
PART_LIST_BYTES = 16 * 1024


class PartList(_Msg):
    """More of the parts a node holds, sent right after the server's welcome when they
    did not all fit its hello (a node offline through a long clinic day holds hundreds);
    the server takes them as the hello's."""

    type: Literal["parts"] = "parts"
    parts: list[PartInfo] = Field(min_length=1, max_length=10000)


def part_batches(parts: Sequence[PartInfo], max_bytes: int = PART_LIST_BYTES
                 ) -> list[list[PartInfo]]:
    """Split a listing into consecutive batches of at most ``max_bytes`` of JSON each.

    A part is never split, and a part larger than ``max_bytes`` alone (it cannot be: its
    fields are bounded) gets a batch of its own.

    Returns:
        The batches in order; none for no parts.
    """
    out: list[list[PartInfo]] = []
    size = max_bytes + 1
    for p in parts:
        n = len(p.model_dump_json()) + 1  # and its comma
        if size + n > max_bytes:
            out.append([])
            size = 0
        out[-1].append(p)
        size += n
    return out


class Pong(_Msg):
    """Reply to :class:`Ping`: t2 = node receive time, t3 = node send time (local clock)."""

    type: Literal["pong"] = "pong"
    seq: int
    t1: float
    t2: float
    t3: float


class NodeStorage(BaseModel):
    """What a node's recordings folder holds and its retention policy (``status``).

    ``unverified`` lists closed parts (newest first, at most 100) the server has not
    confirmed: the server answers ``part_verified`` for those it holds verified, so a
    confirmation lost with a connection or a restart still arrives.
    """

    model_config = ConfigDict(extra="forbid")
    held_bytes: int = 0
    held_parts: int = 0
    verified_bytes: int = 0
    verified_parts: int = 0
    purgeable_bytes: int = 0
    unverified_bytes: int = 0
    unverified_parts: int = 0
    keep_verified_days: float = 7.0
    min_free_bytes: int = 0  # the free-space floor on this node's disk
    purged_parts: int = 0  # since the agent started
    purged_bytes: int = 0
    last_purge: str | None = None
    unverified: list[RecId] = Field(default_factory=list, max_length=100)


class Status(_Msg):
    type: Literal["status"] = "status"
    fps: float = 0.0
    frames: int = 0
    dropped: int = 0
    disk_free_bytes: int | None = None
    ring_seconds: float = 0.0
    storage: NodeStorage | None = None
    diag: dict[str, float] = Field(
        default_factory=dict,
        description="Test-only truths (sim backend with --report-true-clock); never used.",
    )


class RecState(_Msg):
    type: Literal["rec_state"] = "rec_state"
    part: PartInfo


class NodeError(_Msg):
    type: Literal["error"] = "error"
    reason: str = Field(max_length=2000)


#: Characters of a node warning's text (a longer one is cut with an ellipsis).
WARNING_CHARS = 500


class NodeWarning(_Msg):
    """A problem the node's sensor backend ran into after the node connected (body
    tracking stopped, an unreliable device clock, frames dropped), for the Rig page.

    Revision 2 (:data:`PROTOCOL_REVISION`); sent only to a server whose ``welcome``
    accepts ``warning``. The node coalesces repeats of one text (``repeats``: how many
    times it was raised since the last message about it) and sends at most a few a minute
    (:data:`app.nodes.agent.WARNING_BURST`, :data:`app.nodes.agent.WARNING_INTERVAL_S`).
    """

    type: Literal["warning"] = "warning"
    text: Annotated[str, Field(min_length=1, max_length=WARNING_CHARS)]
    t: float = Field(description="Node-local time it was last raised (s).")
    repeats: int = Field(default=1, ge=1, le=1_000_000)

    @field_validator("text", mode="before")
    @classmethod
    def _cut_text(cls, v: Any) -> Any:
        return _cut(v, WARNING_CHARS)


#: Largest image side a camera model may declare (pixels).
MAX_IMAGE_SIDE = 16384


class CameraLens(BaseModel):
    """One camera as a node's ``sensor_lens`` announces it: the image size, the 3×3
    intrinsics at that size and the OpenCV distortion of its lens (k1, k2, p1, p2[, k3[,
    k4, k5, k6[, s1..s4[, τx, τy]]]]; empty: none, an ideal or rectified lens).

    Checked as a calibration capture's camera model is (:func:`check_intrinsics`,
    :func:`check_distortion`).
    """

    model_config = ConfigDict(extra="forbid")
    size: tuple[Annotated[int, Field(ge=1, le=MAX_IMAGE_SIDE)],
                Annotated[int, Field(ge=1, le=MAX_IMAGE_SIDE)]]
    K: list[Annotated[list[float], Field(max_length=3)]] = Field(max_length=3)
    dist: list[float] = Field(default_factory=list, max_length=14)

    @field_validator("K")
    @classmethod
    def _check_K(cls, v: list[list[float]]) -> list[list[float]]:
        return check_intrinsics(v, "K").tolist()

    @field_validator("dist")
    @classmethod
    def _check_dist(cls, v: list[float]) -> list[float]:
        return list(check_distortion(v, "dist")) if v else []


class SensorLens(_Msg):
    """The node's cameras as its sensor reports them, sent once right after the welcome
    (revision 3, only to a server whose ``welcome`` accepts ``sensor_lens``), so the live
    point cloud follows the depth lens before any calibration (an Azure Kinect's factory
    calibration). Each camera's ``size`` and ``K`` are the hello's ``SensorInfo``
    (``depth_size``/``depth_K``, ``color_size``/``color_K``): the server refuses a lens for
    another camera (:func:`lens_mismatch`). A camera left out: its lens is not known.
    """

    type: Literal["sensor_lens"] = "sensor_lens"
    source: Annotated[str, Field(min_length=1, max_length=64)] = Field(
        default="reported by the sensor",
        description="Where the lens comes from, in plain words (\"factory calibration\").")
    depth: CameraLens | None = None
    color: CameraLens | None = None

    @field_validator("source")
    @classmethod
    def _plain_source(cls, v: str) -> str:
        # shown on the Rig page and written to the server's log: no line breaks (forged
        # log lines), control or bidirectional-override characters (a reversed text)
        if any(unicodedata.category(c) in ("Cc", "Cf", "Zl", "Zp") for c in v):
            raise ValueError("source must be plain text on one line (no control, format or "
                             "line-break characters)")
        return v


def lens_mismatch(lens: SensorLens, sensor: SensorInfo) -> str | None:
    """Why ``lens`` does not describe the cameras of ``sensor`` (the node's hello), or
    None when each announced camera has the hello's image size and intrinsics."""
    for name, cam, size, K in (("depth", lens.depth, sensor.depth_size, sensor.depth_K),
                               ("colour", lens.color, sensor.color_size, sensor.color_K)):
        if cam is None:
            continue
        if K is None:
            return f"a {name} lens for a sensor whose hello reported no {name} intrinsics"
        if tuple(cam.size) != tuple(size):
            return (f"the {name} lens is for {cam.size[0]}×{cam.size[1]} images, the hello "
                    f"reported {size[0]}×{size[1]}")
        if not np.allclose(cam.K, np.asarray(K, dtype=float), rtol=1e-6, atol=1e-6):
            return f"the {name} lens's intrinsics K are not those of the hello"
    return None


NodeMessage = Annotated[Hello | PartList | Pong | Status | RecState | NodeError | NodeWarning
                        | SensorLens, Field(discriminator="type")]

# --------------------------------------------------------------------------- server → node


#: Optional node messages a server of this revision takes (``welcome.accepts``).
ACCEPTED_NODE_MESSAGES = ("warning", "sensor_lens")


class Welcome(_Msg):
    type: Literal["welcome"] = "welcome"
    server_time: float
    ping_interval_s: float
    # plain strings: a later server may name messages this node does not know
    accepts: list[Annotated[str, Field(max_length=32)]] | None = Field(
        default=None, max_length=32,
        description="Optional node messages this server takes; sent only to nodes of "
        "revision 2 or later (an older node's parser refuses the field).")


class Refused(_Msg):
    type: Literal["refused"] = "refused"
    reason: str


class Ping(_Msg):
    type: Literal["ping"] = "ping"
    seq: int
    t1: float


class RecStart(_Msg):
    """Record every frame with local time ≥ ``t_start_local`` (from the ring buffer if past)."""

    type: Literal["rec_start"] = "rec_start"
    rec_id: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")
    t_start_server: float
    t_start_local: float
    streams: list[StreamName] = Field(default_factory=list)
    image_every: int = Field(default=1, ge=1, le=1000)
    clock: dict[str, float] = Field(
        default_factory=dict, description="Server's clock model of this node, kept in the part."
    )
    resume: bool = Field(
        default=False,
        description="The recording still runs and the node's part of it was closed early "
        "(the node restarted): record again into that part, after its frames.")
    rebase_s: float = Field(
        default=0.0,
        description="Add this to the node clock's times of the frames recorded now (resume): "
        "the part's first clock model then converts them too (a restarted node's clock, "
        "e.g. a device clock, may count from another origin).")


class RecStop(_Msg):
    """Stop after the last frame with local time ≤ ``t_stop_local`` (waits if in the future)."""

    type: Literal["rec_stop"] = "rec_stop"
    rec_id: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")
    t_stop_server: float
    t_stop_local: float
    clock: dict[str, float] = Field(default_factory=dict)


class Subscribe(_Msg):
    """Stream the named image streams at ``fps`` (0 = stop), downscaled by ``scale``."""

    type: Literal["subscribe"] = "subscribe"
    streams: list[StreamName]
    fps: float = Field(ge=0, le=30)
    scale: float = Field(default=0.5, gt=0, le=1)
    format: Literal["jpeg", "png"] = "jpeg"


class Snapshot(_Msg):
    type: Literal["snapshot"] = "snapshot"
    req_id: int
    streams: list[StreamName]
    scale: float = Field(default=1.0, gt=0, le=1)
    format: Literal["jpeg", "png"] = "png"


class ManifestRequest(_Msg):
    """Describe a closed part for transfer; the node answers with a binary ``manifest``."""

    type: Literal["manifest_request"] = "manifest_request"
    req_id: int
    rec_id: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")


class ChunkRequest(_Msg):
    """Send these chunks of one file of a part, in order, as binary ``chunk`` messages."""

    type: Literal["chunk_request"] = "chunk_request"
    req_id: int
    rec_id: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")
    file: str = Field(min_length=1, max_length=256)
    indices: list[int] = Field(min_length=1, max_length=4096)


class DataChannel(_Msg):
    """Offer of a raw TCP data channel for the chunks of a part (:mod:`app.transfer`):
    connect to the server's ``port`` (same host as the websocket) and present ``token``
    (one-time, bound to this node and part, expires in seconds). A node that cannot (or
    will not: the channel is not encrypted, so a node on ``wss://`` declines) answers a
    binary ``channel`` message (header ``req_id``, ``error``) and the server falls back to
    ``chunk_request`` over the websocket."""

    type: Literal["data_channel"] = "data_channel"
    req_id: int
    rec_id: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")
    port: int = Field(ge=1, le=65535)
    token: str = Field(pattern=r"^[0-9a-f]{32}$")


class CalibrationCapture(_Msg):
    """Send ``frames`` synchronised colour + depth frames at full resolution with the
    camera model, as binary ``calib`` messages (spatial calibration, bumped-tripod check).

    The node answers each frame with :func:`encode_calib_frame` (``index`` 0..frames-1),
    or once with an ``error`` header when it cannot (no colour or depth stream)."""

    type: Literal["calib_capture"] = "calib_capture"
    req_id: int
    frames: int = Field(default=30, ge=1, le=120)


class DeletePart(_Msg):
    """Delete the node's copy of a part (its recording was deleted on the server). The
    node answers on the part-request channel: a binary ``manifest`` message whose header
    carries ``deleted: true`` (or ``error``) and no payload."""

    type: Literal["delete_part"] = "delete_part"
    req_id: int
    rec_id: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")


class PartVerified(_Msg):
    """The server holds a verified copy of the node's part (every chunk and file checked
    against the manifest whose SHA-256 is ``manifest_sha256``). The node checks it against
    its own manifest, notes it (persisted) and may then purge the part by its retention
    policy (:class:`app.nodes.store.RetentionPolicy`). No answer."""

    type: Literal["part_verified"] = "part_verified"
    rec_id: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")
    manifest_sha256: str = Field(pattern=r"^[0-9a-f]{64}$")


class ServerError(_Msg):
    type: Literal["error"] = "error"
    reason: str


ServerMessage = Annotated[
    Welcome | Refused | Ping | RecStart | RecStop | Subscribe | Snapshot | ManifestRequest
    | ChunkRequest | DataChannel | DeletePart | PartVerified | CalibrationCapture | ServerError,
    Field(discriminator="type"),
]

_node_adapter: TypeAdapter[Any] = TypeAdapter(NodeMessage)
_server_adapter: TypeAdapter[Any] = TypeAdapter(ServerMessage)


def _parse(adapter: TypeAdapter[Any], text: str | bytes, limit: int) -> Any:
    if len(text) > limit:
        raise ProtocolError(f"control message of {len(text)} bytes exceeds the {limit}-byte limit")
    try:
        obj = json.loads(text)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ProtocolError(f"control message is not valid JSON: {exc}") from exc
    if not isinstance(obj, dict):
        raise ProtocolError("control message must be a JSON object with a 'type' field")
    if obj.get("v", PROTOCOL_VERSION) != PROTOCOL_VERSION:
        raise ProtocolError(
            f"protocol version {obj.get('v')!r} not supported (this side speaks "
            f"{PROTOCOL_VERSION}); update the node and server to the same gaitrig version"
        )
    try:
        return adapter.validate_python(obj)
    except ValidationError as exc:
        first = exc.errors()[0]
        loc = ".".join(str(x) for x in first.get("loc", ()))
        raise ProtocolError(
            f"invalid {obj.get('type', 'untyped')!r} message: {loc}: {first.get('msg')}"
        ) from exc


def parse_node_message(text: str | bytes, limit: int = 64 * 1024) -> Any:
    """Validate a JSON control message sent by a node.

    Raises:
        ProtocolError: too large, not JSON, wrong version or wrong fields.
    """
    return _parse(_node_adapter, text, limit)


def parse_server_message(text: str | bytes, limit: int = 1024 * 1024) -> Any:
    """Validate a JSON control message sent by the server."""
    return _parse(_server_adapter, text, limit)


def dump(msg: BaseModel) -> str:
    """Serialise a control message (an optional field left at None is left out: a peer of
    an older revision refuses fields it does not know)."""
    if isinstance(msg, Welcome) and msg.accepts is None:
        return msg.model_dump_json(exclude={"accepts"})
    return msg.model_dump_json()


# --------------------------------------------------------------------------- binary


def encode_binary(header: dict[str, Any], payload: bytes | memoryview = b"") -> bytes:
    """Pack a bulk message: magic+version, header length, JSON header, payload."""
    h = json.dumps(header, separators=(",", ":")).encode()
    return _HDR.pack(BINARY_MAGIC, len(h)) + h + bytes(payload)


def decode_binary(data: bytes, limit: int = 16 * 1024 * 1024) -> tuple[dict[str, Any], bytes]:
    """Unpack a bulk message into ``(header, payload)``.

    Raises:
        ProtocolError: too large, wrong magic/version, bad header.
    """
    if len(data) > limit:
        raise ProtocolError(f"binary message of {len(data)} bytes exceeds the {limit}-byte limit")
    if len(data) < _HDR.size:
        raise ProtocolError("binary message shorter than its 8-byte prefix")
    magic, hlen = _HDR.unpack_from(data)
    if magic[:3] != BINARY_MAGIC[:3]:
        raise ProtocolError("binary message does not start with the gaitrig magic 'GRB'")
    if magic[3] != PROTOCOL_VERSION:
        raise ProtocolError(f"binary protocol version {magic[3]} not supported")
    if hlen > MAX_BINARY_HEADER or _HDR.size + hlen > len(data):
        raise ProtocolError(f"binary header length {hlen} is inconsistent with the message")
    try:
        header = json.loads(data[_HDR.size : _HDR.size + hlen])
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ProtocolError(f"binary header is not valid JSON: {exc}") from exc
    if not isinstance(header, dict) or header.get("kind") not in BINARY_KINDS:
        raise ProtocolError(
            f"binary header must be an object with kind in {', '.join(BINARY_KINDS)}")
    return header, data[_HDR.size + hlen :]


def encode_skeletons(
    seq: int,
    t_local: float,
    positions: NDArray[np.floating[Any]],
    states: NDArray[np.integer[Any]],
    body_ids: list[int] | None = None,
) -> bytes:
    """Binary skeleton frame: ``positions (B, J, 3)`` metres, ``states (B, J)`` uint8."""
    pos = np.ascontiguousarray(positions, dtype="<f4")
    st = np.ascontiguousarray(states, dtype=np.uint8)
    if pos.ndim != 3 or pos.shape[2] != 3 or st.shape != pos.shape[:2]:
        raise ProtocolError(
            f"skeleton arrays must be (B, J, 3) and (B, J), got {pos.shape} and {st.shape}"
        )
    B, J = st.shape
    ids = list(body_ids) if body_ids is not None else list(range(B))
    header = {"kind": "skeleton", "seq": int(seq), "t": float(t_local), "bodies": ids, "joints": J}
    return encode_binary(header, pos.tobytes() + st.tobytes())


def decode_skeletons(
    header: dict[str, Any], payload: bytes
) -> tuple[NDArray[np.float32], NDArray[np.uint8]]:
    """Inverse of :func:`encode_skeletons` (after :func:`decode_binary`)."""
    try:
        B = len(header["bodies"])
        J = int(header["joints"])
        float(header["t"])
        int(header["seq"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ProtocolError(f"skeleton header lacks a valid field: {exc}") from exc
    if not (0 <= B <= 16 and 0 < J <= 64):
        raise ProtocolError(f"skeleton header has {B} bodies × {J} joints; limits are 16 × 64")
    n_pos = B * J * 3 * 4
    if len(payload) != n_pos + B * J:
        raise ProtocolError(
            f"skeleton payload is {len(payload)} bytes, expected {n_pos + B * J} for {B}×{J}"
        )
    pos = np.frombuffer(payload, dtype="<f4", count=B * J * 3).reshape(B, J, 3)
    st = np.frombuffer(payload, dtype=np.uint8, offset=n_pos).reshape(B, J)
    return pos, st


# --------------------------------------------------------------------------- calibration


def _png(img: NDArray[Any]) -> bytes:
    import cv2

    ok, buf = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise ProtocolError(f"could not encode a {img.shape} {img.dtype} image as PNG")
    return bytes(buf.tobytes())


def encode_calib_frame(
    req_id: int, index: int, frames: int, t_local: float, color: NDArray[Any],
    depth: NDArray[Any], color_K: ArrayLike, depth_K: ArrayLike,
    T_depth_color: ArrayLike, depth_scale: float = 1000.0,
    color_dist: ArrayLike | None = None, depth_dist: ArrayLike | None = None,
) -> bytes:
    """Binary ``calib`` message: one colour + depth frame of a calibration capture.

    The colour image is sent as 8-bit grey PNG (marker detection works on grey; a third
    of the bytes), the depth as 16-bit PNG; both lossless so sub-pixel corners and depth
    noise arrive as captured. The header carries the camera model: 3×3 intrinsics of each
    image at its sent size, ``T_depth_color`` (colour → depth camera), ``depth_scale``
    (raw units per metre) and, when the lens has one, each image's OpenCV distortion
    (``color_dist``/``depth_dist``: k1, k2, p1, p2[, k3[, k4, k5, k6]]; absent = none, as
    older nodes send).
    """
    import cv2

    c = np.asarray(color)
    if c.ndim == 3:
        c = cv2.cvtColor(c, cv2.COLOR_RGB2GRAY)
    d = np.asarray(depth)
    if d.ndim != 2 or c.ndim != 2:
        raise ProtocolError(f"calibration frame needs 2-D depth and colour, got {d.shape}, "
                            f"{np.asarray(color).shape}")
    cb, db = _png(c.astype(np.uint8)), _png(d.astype(np.uint16))
    header = {"kind": "calib", "req_id": int(req_id), "index": int(index),
              "frames": int(frames), "t": float(t_local), "color_bytes": len(cb),
              "color_K": np.asarray(color_K, float).tolist(),
              "depth_K": np.asarray(depth_K, float).tolist(),
              "T_depth_color": np.asarray(T_depth_color, float).tolist(),
              "depth_scale": float(depth_scale)}
    for key, dist in (("color_dist", color_dist), ("depth_dist", depth_dist)):
        if dist is not None and np.any(np.asarray(dist, float) != 0):
            header[key] = np.asarray(dist, float).ravel().tolist()
    return encode_binary(header, cb + db)


#: lengths of an OpenCV distortion vector
_DIST_LENGTHS = (4, 5, 8, 12, 14)


def check_distortion(v: Any, what: str) -> tuple[float, ...]:
    """OpenCV distortion coefficients ``v`` checked (a calibration capture's ``calib``
    header and a node's ``sensor_lens`` alike).

    Raises:
        ProtocolError: not a list of 4, 5, 8, 12 or 14 finite numbers (``what`` names it).
    """
    try:
        d = np.asarray(v, dtype=float).ravel()
    except (TypeError, ValueError) as exc:
        raise ProtocolError(f"{what} is not a list of numbers") from exc
    if d.size not in _DIST_LENGTHS or not np.all(np.isfinite(d)):
        raise ProtocolError(f"{what} must be 4, 5, 8, 12 or 14 finite OpenCV "
                            f"distortion coefficients, got {d.size}")
    return tuple(float(x) for x in d)


def check_intrinsics(v: Any, what: str) -> NDArray[np.float64]:
    """A 3×3 camera matrix ``v`` checked: finite, positive focal lengths.

    Raises:
        ProtocolError: it is not (``what`` names it).
    """
    try:
        K = np.asarray(v, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ProtocolError(f"{what} is not a 3×3 matrix of numbers") from exc
    if K.shape != (3, 3):
        raise ProtocolError(f"{what} is not 3×3 (shape {K.shape})")
    if not np.all(np.isfinite(K)) or not (K[0, 0] > 0 and K[1, 1] > 0):
        raise ProtocolError(f"{what} needs finite numbers and positive focal lengths")
    return K


def calib_distortion(header: dict[str, Any], key: str) -> tuple[float, ...]:
    """The OpenCV distortion ``key`` (``color_dist``/``depth_dist``) of a ``calib``
    header; ``()`` (no distortion) when absent, as older nodes send.

    Raises:
        ProtocolError: not a list of 4, 5, 8, 12 or 14 finite numbers.
    """
    v = header.get(key)
    if v is None:
        return ()
    return check_distortion(v, f"calib header {key}")


def calib_error(req_id: int, reason: str) -> bytes:
    """Binary ``calib`` message saying why the node cannot send calibration frames."""
    return encode_binary({"kind": "calib", "req_id": int(req_id), "error": reason[:2000]})


def decode_calib_frame(header: dict[str, Any], payload: bytes
                       ) -> tuple[NDArray[np.uint8], NDArray[np.uint16]]:
    """Colour (grey) and depth images of a ``calib`` message (after :func:`decode_binary`).

    Raises:
        ProtocolError: missing fields or undecodable images.
    """
    import cv2

    try:
        n = int(header["color_bytes"])
        for k in ("color_K", "depth_K"):
            check_intrinsics(header[k], k)
        if np.asarray(header["T_depth_color"], float).shape != (4, 4):
            raise ValueError("T_depth_color is not 4×4")
        if not float(header["depth_scale"]) > 0:
            raise ValueError("depth_scale must be positive")
        calib_distortion(header, "color_dist")
        calib_distortion(header, "depth_dist")
    except (KeyError, TypeError, ValueError) as exc:
        raise ProtocolError(f"calib header lacks a valid field: {exc}") from exc
    if not 0 < n < len(payload):
        raise ProtocolError(f"calib payload of {len(payload)} bytes cannot hold a {n}-byte "
                            "colour image and a depth image")
    c = cv2.imdecode(np.frombuffer(payload[:n], np.uint8), cv2.IMREAD_UNCHANGED)
    d = cv2.imdecode(np.frombuffer(payload[n:], np.uint8), cv2.IMREAD_UNCHANGED)
    if c is None or d is None or c.dtype != np.uint8 or d.dtype != np.uint16 or d.ndim != 2:
        raise ProtocolError("calib frame images are not an 8-bit colour/grey PNG and a "
                            "16-bit depth PNG")
    return np.asarray(c, np.uint8), np.asarray(d, np.uint16)
