"""A simulated lab in motion: rig + walkers + per-sensor frame schedules and skeletons.

:class:`SimWorld` is what a ``sim`` node backend calls about 30 times a second per sensor.
Frame times (jittering 25–35 Hz) and skeleton observations are generated in chunks of
``chunk_s`` seconds, sequentially per sensor and deterministically from ``seed``, so a
call is a lookup; only depth/colour rendering costs real work per frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from engine.errors import InputError
from engine.sim.clock import frame_times
from engine.sim.render import SensorRenderer, SimFrame
from engine.sim.rig import Rig
from engine.sim.skeleton_model import SkeletonErrorModel, observe_skeletons
from engine.sim.walker import Walker
from engine.skeleton import SkeletonSeries


@dataclass
class _Chunk:
    t0: float
    t1: float
    times: NDArray[np.float64]
    series: list[SkeletonSeries]


@dataclass
class _SensorState:
    index: int
    chunks: list[_Chunk] = field(default_factory=list)
    renderer: SensorRenderer | None = None


class SimWorld:
    """Ties a rig and walkers together.

    Args:
        rig: The rig.
        walkers: The subjects (body index = position in the list).
        seed: Seed of frame jitter, skeleton errors and depth noise.
        model: Skeleton error model (default :class:`SkeletonErrorModel`).
        color_size: Colour render size, or ``None`` for no colour.
        chunk_s: Length of the pre-computed frame/skeleton chunks (s).
        start_time: True time of the world's first frames (s).
    """

    def __init__(self, rig: Rig, walkers: list[Walker], seed: int = 0,
                 model: SkeletonErrorModel | None = None,
                 color_size: tuple[int, int] | None = (640, 360), chunk_s: float = 20.0,
                 start_time: float = 0.0) -> None:
        if chunk_s < 1.0:
            raise InputError("chunk_s must be at least 1 s")
        self.rig = rig
        self.walkers = list(walkers)
        self.seed = int(seed)
        self.model = model or SkeletonErrorModel()
        self.color_size = color_size
        self.chunk_s = float(chunk_s)
        self.start_time = float(start_time)
        self._state = {s.id: _SensorState(i) for i, s in enumerate(rig.sensors)}

    def _sensor_state(self, sensor_id: str) -> _SensorState:
        if sensor_id not in self._state:
            raise InputError(f"no sensor {sensor_id!r} in the simulated rig; sensors are "
                             f"{', '.join(self._state)}")
        return self._state[sensor_id]

    def _ensure(self, sensor_id: str, t_true: float) -> _SensorState:
        st = self._sensor_state(sensor_id)
        sensor = self.rig.sensor(sensor_id)
        while not st.chunks or st.chunks[-1].t1 <= t_true:
            k = len(st.chunks)
            rng = np.random.default_rng([self.seed, st.index, k])
            if st.chunks:
                last = st.chunks[-1]
                t0 = float(last.times[-1]) + float(
                    np.clip(1.0 / sensor.fps_nominal, 1 / 35, 1 / 25))
            else:
                t0 = self.start_time + rng.uniform(0.0, 1.0 / sensor.fps_nominal)
            t1 = self.start_time + (k + 1) * self.chunk_s
            times = frame_times(t0, t1, rng, sensor.fps_nominal, sensor.fps_jitter)
            series = [observe_skeletons(sensor, self.rig, w, times, rng, self.model, body_id=b)
                      for b, w in enumerate(self.walkers)]
            st.chunks.append(_Chunk(t0, t1, times, series))
        return st

    def frame_times(self, sensor_id: str, t0: float, t1: float) -> NDArray[np.float64]:
        """True capture times of the sensor's frames within ``[t0, t1]``.

        Args:
            sensor_id: Sensor id.
            t0: Start, s (true clock).
            t1: End, s (true clock).

        Returns:
            ``(N,)`` true times, s.
        """
        st = self._ensure(sensor_id, t1)
        ts = np.concatenate([c.times for c in st.chunks])
        return ts[(ts >= t0) & (ts <= t1)]

    def skeletons(self, sensor_id: str, t0: float, t1: float) -> list[SkeletonSeries]:
        """Per body, the sensor's skeleton series for frames captured within true ``[t0, t1]``.

        Args:
            sensor_id: Sensor id.
            t0: Start, s (true clock).
            t1: End, s (true clock).

        Returns:
            One series per walker (sensor frame, the sensor's local clock).
        """
        st = self._ensure(sensor_id, t1)
        out = []
        for b in range(len(self.walkers)):
            parts = [c.series[b] for c in st.chunks if c.t1 >= t0 and c.t0 <= t1]
            tt = np.concatenate([p.meta["times_true"] for p in parts])
            m = (tt >= t0) & (tt <= t1)
            meta = dict(parts[0].meta)
            for key in ("times_true", "times_local", "body_tracked", "mirrored", "leg_swapped",
                        "occluded", "hidden_tracked"):
                meta[key] = np.concatenate([p.meta[key] for p in parts])[m]
            out.append(SkeletonSeries(
                times=np.concatenate([p.times for p in parts])[m],
                positions=np.concatenate([p.positions for p in parts])[m],
                states=np.concatenate([p.states for p in parts])[m],
                meta=meta))
        return out

    def frame(self, sensor_id: str, t_true: float, render: bool = True,
              with_color: bool = True) -> SimFrame:
        """The sensor's latest frame captured at or before ``t_true``.

        Args:
            sensor_id: Sensor id.
            t_true: True time (s), ≥ the world's first frame.
            render: Ray-cast depth/body index (and colour); otherwise the images are empty
                (0 × 0) and only the skeletons are returned. The body index marks only
                bodies whose skeleton is tracked in that frame, as the Kinect SDK does.
            with_color: Also render colour (when ``render``).

        Returns:
            A :class:`SimFrame`; ``meta["skeletons"]`` lists, per tracked body, a dict with
            ``body_id``, ``positions`` (25, 3) in the sensor frame (m, NaN = none) and
            ``states`` (25,) uint8; ``meta["frame_index"]`` counts frames from the start.
        """
        st = self._ensure(sensor_id, float(t_true))
        sensor = self.rig.sensor(sensor_id)
        offset = 0
        for chunk in st.chunks:
            if chunk.t1 > t_true:
                break
            offset += len(chunk.times)
        i = int(np.searchsorted(chunk.times, t_true, side="right")) - 1
        if i < 0:  # before the chunk's first frame: the previous chunk's last one
            if chunk is st.chunks[0]:
                raise InputError(f"no frame of {sensor_id} at or before t = {t_true:.3f} s "
                                 f"(the simulation starts at {self.start_time:.3f} s)")
            chunk = st.chunks[st.chunks.index(chunk) - 1]
            offset -= len(chunk.times)
            i = len(chunk.times) - 1
        t = float(chunk.times[i])
        skels = []
        for b, ser in enumerate(chunk.series):
            if ser.meta["body_tracked"][i]:
                skels.append({"body_id": b, "positions": ser.positions[i].copy(),
                              "states": ser.states[i].copy()})
        if render:
            if st.renderer is None:
                st.renderer = SensorRenderer(sensor, self.rig, self.color_size)
            rng = np.random.default_rng([self.seed, st.index, 1_000_000 + offset + i])
            meshes = [w.body_mesh(t) for w in self.walkers]
            fr = st.renderer.render(meshes, rng, with_color=with_color)
            # like the Kinect SDK, the body-index image shows tracked bodies only
            for b, ser in enumerate(chunk.series):
                if not ser.meta["body_tracked"][i]:
                    fr.body_index[fr.body_index == b] = 255
        else:
            empty = np.zeros((0, 0), dtype=np.uint16)
            fr = SimFrame(sensor_id=sensor_id, depth=empty,
                          body_index=np.zeros((0, 0), dtype=np.uint8), color=None,
                          K_depth=sensor.model.depth_intrinsics(), K_color=None)
        fr.time_true = t
        fr.time_local = float(sensor.clock.local(t))
        fr.meta["skeletons"] = skels
        fr.meta["frame_index"] = offset + i
        return fr
