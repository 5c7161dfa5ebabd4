"""``replay`` backend: plays a node's recording part back as if it were a live sensor.

Frames are paced by their recorded time differences and re-stamped on the host clock
(``t_local = start + (t_recorded - t_first)``), so the server treats the replay like any
node. Recorded images are served for the frame they belong to.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from app.nodes.backends.base import LATE_WARN_EVERY_S, LATE_WARN_S, Backend, Frame
from app.nodes.protocol import SensorInfo, decode_skeletons
from app.nodes.store import NodeStore
from engine.errors import InputError


class ReplayBackend(Backend):
    """Replays ``<recordings>/<rec_id>`` written by :class:`app.nodes.store.NodeStore`.

    Args:
        part_dir: the part's folder (holding ``meta.json`` and ``frames.bin``).
        loop: start over at the end instead of finishing.
        speed: playback speed factor.
    """

    name = "replay"

    def __init__(self, part_dir: Path | str, loop: bool = False, speed: float = 1.0) -> None:
        part_dir = Path(part_dir)
        if not (part_dir / "frames.bin").exists():
            raise InputError(f"{part_dir} is not a recording part (no frames.bin); give the "
                             "folder <node data>/recordings/<recording id>")
        if speed <= 0:
            raise InputError("replay speed must be positive")
        self.store = NodeStore(part_dir.parent)
        self.rec_id = part_dir.name
        self.loop, self.speed = loop, speed
        self._closed = threading.Event()
        self._late_warned = time.time()  # not in the first minute: starting is slow anyway

    def open(self) -> SensorInfo:
        meta = self.store.meta(self.rec_id)
        rate = 30.0
        if meta.get("n_frames") and meta.get("t_first") is not None and meta.get("t_last"):
            span = float(meta["t_last"]) - float(meta["t_first"])
            rate = (int(meta["n_frames"]) - 1) / span if span > 0 else 30.0
        return SensorInfo(model=f"replay of {self.rec_id} ({meta.get('node_id', '?')})",
                          rate_hz=rate)

    def now(self) -> float:
        return time.time()

    def close(self) -> None:
        self._closed.set()

    def frames(self) -> Iterator[Frame]:
        while not self._closed.is_set():
            t0_rec: float | None = None
            t0 = time.time()
            pending: list[tuple[float, NDArray[np.float32], NDArray[np.uint8], list[int]]] = []
            images: dict[float, dict[str, bytes]] = {}
            for header, payload in self.store.read(self.rec_id):
                t = float(header["t"])
                if header["kind"] == "image":
                    images.setdefault(t, {})[str(header["stream"])] = payload
                    continue
                pos, st = decode_skeletons(header, payload)
                pending.append((t, pos, st, [int(b) for b in header["bodies"]]))
            for t, pos, st, ids in pending:
                if t0_rec is None:
                    t0_rec = t
                t_play = t0 + (t - t0_rec) / self.speed
                now = time.time()
                delay = t_play - now
                if delay > 0 and self._closed.wait(delay):
                    return
                if -delay > LATE_WARN_S and now - self._late_warned >= LATE_WARN_EVERY_S:
                    self._late_warned = now
                    self.warn(f"The replay of {self.rec_id} runs {-delay:.1f} s behind its "
                              "recorded pace: this computer cannot keep up, frames come "
                              "late. Stop other work on this computer.")
                yield Frame(t_play, pos.copy(), st.copy(), ids, _Images(images.get(t, {})))
            if not self.loop or not pending:
                return


class _Images:
    def __init__(self, encoded: dict[str, bytes]) -> None:
        self.encoded = encoded

    def __call__(self, streams: Sequence[str]) -> dict[str, NDArray[np.uint8] | NDArray[np.uint16]]:
        out: dict[str, NDArray[np.uint8] | NDArray[np.uint16]] = {}
        for s in streams:
            if s in self.encoded:
                img: Any = cv2.imdecode(np.frombuffer(self.encoded[s], np.uint8),
                                        cv2.IMREAD_UNCHANGED)
                if img is not None:
                    out[s] = cv2.cvtColor(img, cv2.COLOR_BGR2RGB) if s == "color" else img
        return out
