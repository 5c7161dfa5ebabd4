"""``sim`` backend: one simulated Kinect v2 of the simulated lab (:mod:`engine.sim`).

All sim nodes share one simulated world without talking to each other: the walker's
true time is the host clock modulo :data:`WORLD_CYCLE_S` (a new walk — standing start,
then back and forth along the corridor — begins every ten minutes on the wall clock), so
six node processes on one machine, or in six containers, see the same person at the same
instant. Each node's local clock gets the sensor's offset and drift (``NodeClock``), which
is what the server has to measure.

Skeletons come from :func:`engine.sim.skeleton_model.observe_skeletons`, evaluated on
chunks of :data:`CHUNK_S` seconds of jittered frame times ahead of real time (the error
model's slowly varying errors restart at chunk boundaries). Frames are released at their
capture instants. Images are rendered only when asked for (recording with images or a
subscription) by :class:`engine.sim.render.SensorRenderer`: recordings and snapshots at
full size, the live panels' subscription directly at its scale (``Frame.preview``), which
costs a quarter of a full frame at the usual half size.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.nodes.backends.base import (
    LATE_WARN_EVERY_S,
    LATE_WARN_S,
    Backend,
    Frame,
    downscale_image,
)
from app.nodes.clock import NodeClock
from app.nodes.protocol import SensorInfo
from engine.errors import InputError

log = logging.getLogger("gaitrig.node")

WORLD_CYCLE_S = 600.0
CHUNK_S = 10.0
#: ``test_warning`` (``gaitrig node --test-warning``) is raised this often.
TEST_WARNING_EVERY_S = 5.0


def world_time(t_host: float) -> float:
    """True simulation time (s into the current walk) at host time ``t_host``."""
    return t_host % WORLD_CYCLE_S


class SimBackend(Backend):
    """A simulated sensor.

    Args:
        sensor_id: sensor of the rig (``S1`` .. ``S6`` in the default avenue).
        rig_path: rig file (TOML/JSON); default :func:`engine.sim.rig.default_avenue_rig`.
        seed: seed of the rig, the walker and the errors (the same for all nodes of a demo,
            so they simulate the same subject).
        clock_offset_s: override the sensor's clock offset (s).
        clock_drift_ppm: override its drift (ppm).
        images: render images on demand (False: skeletons only, for light test runs).
        report_truth: expose the true clock offset through :meth:`diagnostics` (tests).
        test_warning: TEST ONLY: raise this backend warning (:meth:`Backend.warn`) every
            :data:`TEST_WARNING_EVERY_S` seconds, as a sensor in trouble would.
    """

    name = "sim"
    lens_source = "simulator"  # its GAITRIG_TEST_SIM_*_DIST lenses, or none

    def __init__(self, sensor_id: str, rig_path: Path | str | None = None, seed: int = 0,
                 clock_offset_s: float | None = None, clock_drift_ppm: float | None = None,
                 images: bool = True, report_truth: bool = False,
                 test_warning: str | None = None) -> None:
        from engine.sim.rig import default_avenue_rig, load_rig

        self.rig = load_rig(rig_path) if rig_path is not None else default_avenue_rig(seed)
        self.sensor = self.rig.sensor(sensor_id)
        if clock_offset_s is not None:
            if abs(clock_offset_s) > 10.0:
                raise InputError("--clock-offset must be within ±10 s")
            self.sensor.clock_offset_s = clock_offset_s
        if clock_drift_ppm is not None:
            if abs(clock_drift_ppm) > 1000.0:
                raise InputError("--clock-drift-ppm must be within ±1000 ppm")
            self.sensor.clock_drift_ppm = clock_drift_ppm
        self.seed = seed
        self.clock = NodeClock(self.sensor.clock_offset_s, self.sensor.clock_drift_ppm * 1e-6,
                               t_ref=time.time())
        self.render_images = images
        self.report_truth = report_truth
        self.test_warning = test_warning
        self._step_file = os.environ.get("GAITRIG_TEST_CLOCK_STEP_FILE") or None
        # TEST HOOKS (GAITRIG_TEST_SIM_COLOR_DIST / _DEPTH_DIST=k1,k2,p1,p2[,k3...]): the
        # colour (calibration frames) and depth (every frame) are rendered through these
        # lenses, which the node then reports like a real sensor's (Backend.color_dist,
        # depth_dist); the simulated rig has none by default
        for attr, var in (("color_dist", "GAITRIG_TEST_SIM_COLOR_DIST"),
                          ("depth_dist", "GAITRIG_TEST_SIM_DEPTH_DIST")):
            lens = os.environ.get(var)
            if lens:
                try:
                    setattr(self, attr, [float(x) for x in lens.split(",")])
                except ValueError as exc:
                    raise InputError(f"{var} must be comma-separated numbers, got "
                                     f"{lens!r}") from exc
        self._step: tuple[float, float] | None = None  # (host time, seconds) of the step
        self._closed = threading.Event()
        self._walker: Any = None
        self._renderer: Any = None
        self._previews: dict[float, Any] = {}  # image scale → preview renderer
        self._render_lock = threading.Lock()
        self._calib_renderer: Any = None  # colour at the calibration size (lazy)
        self._calib_lock = threading.Lock()
        self._calib_rng = np.random.default_rng([seed, 11, sum(ord(c) for c in sensor_id)])
        self._img_rng = np.random.default_rng([seed, 7, sum(ord(c) for c in sensor_id)])
        # sensor-specific stream of randomness, reproducible per (seed, sensor)
        self._rng = np.random.default_rng([seed, sum(ord(c) for c in sensor_id)])

    def open(self) -> SensorInfo:
        from engine.sim.walker import Walker, WalkerParams

        w = self.rig.walkway
        self._walker = Walker(WalkerParams.random(np.random.default_rng(self.seed)), w.start,
                              w.end, start_time=0.0, seed=self.seed,
                              horizon_s=WORLD_CYCLE_S + CHUNK_S)
        self._chunk(time.time())  # warm up (imports, caches) so the first frames are on time
        m = self.sensor.model
        return SensorInfo(
            model="simulated Kinect v2",
            depth_size=(m.depth_width, m.depth_height),
            color_size=(m.color_render_width, m.color_render_height),
            depth_K=m.depth_intrinsics().tolist(), color_K=m.color_intrinsics().tolist(),
            fov_deg=(m.depth_hfov_deg, m.depth_vfov_deg), rate_hz=self.sensor.fps_nominal,
            joint_set="kinect_v2", T_world_sensor=np.asarray(self.sensor.T_world_sensor).tolist(),
        )

    def now(self) -> float:
        return self._local(time.time())

    def _local(self, t_host: float) -> float:
        """The node clock at host time ``t_host``, with the test hook's step."""
        t = self.clock.from_host(t_host)
        if self._step_file is None:
            return t
        if self._step is None:
            # TEST HOOK (GAITRIG_TEST_CLOCK_STEP_FILE=<path>): once the file exists, this
            # node's clock jumps by the seconds written in it (an NTP step) from then on
            try:
                seconds = float(Path(self._step_file).read_text())
            except (OSError, ValueError):
                return t
            self._step = (time.time(), seconds)
            log.warning("TEST HOOK: the node clock steps by %+.3f s", seconds)
        return t + (self._step[1] if t_host >= self._step[0] else 0.0)

    def close(self) -> None:
        self._closed.set()

    def diagnostics(self, t_host: float) -> dict[str, float]:
        if not self.report_truth:
            return {}
        return {"true_offset_s": self.clock.true_offset(t_host), "t_host": t_host,
                "true_offset_at_ref_s": self.clock.offset_s, "true_drift": self.clock.drift,
                "clock_t_ref": self.clock.t_ref}

    def _chunk(self, t_host0: float) -> tuple[NDArray[np.float64], Any, float, Any]:
        """Host capture times in [t_host0, t_host0 + CHUNK_S), their observed skeletons and
        (with images) the body's capsules at those times — for the whole chunk at once,
        a fraction of the cost of posing the walker for each rendered frame."""
        from engine.sim.clock import frame_times
        from engine.sim.skeleton_model import observe_skeletons

        w0 = world_time(t_host0)
        w1 = min(w0 + CHUNK_S, WORLD_CYCLE_S)  # a walk ends at the cycle boundary
        tw = frame_times(w0, w1, self._rng, fps=self.sensor.fps_nominal,
                         jitter=self.sensor.fps_jitter)
        series = observe_skeletons(self.sensor, self.rig, self._walker, tw, self._rng)
        caps = (self._walker.capsule_segments(tw) if self.render_images and len(tw)
                else None)
        return t_host0 + (tw - w0), series, t_host0, caps

    def frames(self) -> Iterator[Frame]:
        if self._walker is None:
            raise InputError("SimBackend.open() must be called before frames()")
        period = 1.0 / self.sensor.fps_nominal
        # The next chunk is simulated in a helper thread while this one plays, so frames
        # keep their pace.
        next_test_warning = time.time() + 1.0
        late_warned = time.time()  # not in the first minute: starting up is slow anyway
        with ThreadPoolExecutor(max_workers=1, thread_name_prefix="sim") as pool:
            fut = pool.submit(self._chunk, time.time() + 0.3)
            while not self._closed.is_set():
                hosts, series, t0, caps = fut.result()
                if len(hosts) == 0:  # the chunk began in the last frame of a walk
                    fut = pool.submit(self._chunk, t0 + WORLD_CYCLE_S - world_time(t0) + 1e-3)
                    continue
                hosts_end = float(hosts[-1]) + period
                fut = pool.submit(self._chunk, hosts_end)
                tracked = series.meta["body_tracked"]
                for k, t_host in enumerate(hosts):
                    now = time.time()
                    delay = t_host - now
                    if delay > 0 and self._closed.wait(delay):
                        return
                    if -delay > LATE_WARN_S and now - late_warned >= LATE_WARN_EVERY_S:
                        late_warned = now
                        self.warn(f"The simulated sensor {self.sensor.id} runs {-delay:.1f} s "
                                  "behind real time: this computer cannot keep up, frames "
                                  "come late. Run fewer simulated nodes or stop other work.")
                    if self.test_warning and now >= next_test_warning:
                        next_test_warning = now + TEST_WARNING_EVERY_S
                        self.warn(self.test_warning)
                    if tracked[k]:
                        pos = series.positions[k : k + 1].astype(np.float32)
                        st = series.states[k : k + 1]
                        ids = [0]
                    else:
                        pos = np.zeros((0, 25, 3), np.float32)
                        st = np.zeros((0, 25), np.uint8)
                        ids = []
                    seg = None if caps is None else (caps[0][k], caps[1][k], caps[2])
                    yield Frame(self._local(float(t_host)), pos, st, ids,
                                self._image_fn(float(t_host), seg),
                                self._preview_fn(float(t_host), seg))

    def _image_fn(self, t_host: float, capsules: Any = None) -> Any:
        if not self.render_images:
            return _no_images
        t_world = world_time(t_host)

        def images(streams: Sequence[str]) -> dict[str, NDArray[np.uint8] | NDArray[np.uint16]]:
            return self.render(t_world, streams, capsules=capsules)

        return images

    def _preview_fn(self, t_host: float, capsules: Any = None) -> Any:
        if not self.render_images:
            return None
        t_world = world_time(t_host)

        def preview(streams: Sequence[str], scale: float
                    ) -> dict[str, NDArray[np.uint8] | NDArray[np.uint16]]:
            return self.render(t_world, streams, scale, capsules)

        return preview

    def render(self, t_world: float, streams: Sequence[str], scale: float = 1.0,
               capsules: tuple[Any, Any, Any] | None = None
               ) -> dict[str, NDArray[np.uint8] | NDArray[np.uint16]]:
        """Depth (uint16 mm), body index (uint8, 255 = none) and colour (RGB) at ``t_world``.

        Called from the agent's image thread; the renderers (room ray-cast once) are built
        on first use.

        Args:
            t_world: simulation time (s).
            streams: which images.
            scale: < 1 renders depth and body index directly at this fraction of the
                sensor's size (a live preview: the geometry of a nearest-neighbour
                downscale, a fraction of the cost); colour, if asked for, stays full size.
            capsules: the body's capsules ``(A, B, radii)`` at ``t_world`` if known (the
                frame loop poses whole chunks); None: posed here.
        """
        from engine.sim.render import SensorRenderer
        from engine.sim.walker import capsules_mesh

        want_color = "color" in streams
        # colour is only rendered at full size: with colour, everything is rendered at full
        # size and downscaled below (as the agent would)
        preview = scale != 1.0 and not want_color
        with self._render_lock:
            mesh = (capsules_mesh(*capsules) if capsules is not None
                    else self._walker.body_mesh(t_world))
            if preview:
                r = self._previews.get(scale)
                if r is None:
                    if len(self._previews) >= 4:  # a few scales at most (bounded memory)
                        self._previews.clear()
                    r = self._previews[scale] = SensorRenderer(
                        self.sensor, self.rig, None, image_scale=scale,
                        depth_dist=self.depth_dist)
            else:
                if self._renderer is None:
                    m = self.sensor.model
                    self._renderer = SensorRenderer(
                        self.sensor, self.rig, (m.color_render_width, m.color_render_height),
                        depth_dist=self.depth_dist)
                r = self._renderer
            frame = r.render([mesh], self._img_rng, with_color=want_color)
        out: dict[str, NDArray[np.uint8] | NDArray[np.uint16]] = {}
        if "depth" in streams:
            out["depth"] = frame.depth
        if "body_index" in streams:
            out["body_index"] = frame.body_index
        if want_color and frame.color is not None:
            out["color"] = frame.color
        if scale != 1.0 and not preview:
            out = {k: downscale_image(k, v, scale) for k, v in out.items()}
        return out

    def calibration_frames(self, n: int) -> Iterator[tuple[Any, ...]]:
        """``n`` colour + depth frames for the spatial calibration (the agent sends them).

        The colour camera is rendered at :data:`engine.calibration.simcapture.
        CAPTURE_COLOR_SIZE` (the streaming size is too small to decode floor markers 4 m
        away; a real Kinect's colour is 1920×1080), with depth noise and colour read
        noise, of the room without the walker: the wizard asks for a clear room, and the
        simulated person (who starts each walk standing near marker 1) steps out for
        the capture.

        Yields:
            ``(t_local, colour RGB, depth uint16 mm, colour K, depth K, T_depth_color,
            depth_scale)``.

        Raises:
            InputError: the node was started without images.
        """
        from engine.calibration.simcapture import CAPTURE_COLOR_SIZE, render_sensor_frames
        from engine.sim.render import SensorRenderer

        if not self.render_images or self._walker is None:
            raise InputError("this simulated node was started with --no-images (or not "
                             "opened): it has no colour or depth images to calibrate with")
        with self._calib_lock:
            if self._calib_renderer is None:
                self._calib_renderer = SensorRenderer(self.sensor, self.rig, CAPTURE_COLOR_SIZE,
                                                      color_dist=self.color_dist,
                                                      depth_dist=self.depth_dist)
            r = self._calib_renderer
        for _ in range(n):
            t_host = time.time()
            with self._calib_lock:
                sf = render_sensor_frames(self.sensor, self.rig, 1, self._calib_rng,
                                          CAPTURE_COLOR_SIZE, bodies=None, renderer=r)
            assert sf.depths is not None
            yield (self._local(t_host), sf.colors[0], sf.depths[0], r.K_color,
                   r.K_depth, self.sensor.model.T_depth_color, sf.depth_scale)


def _no_images(streams: Sequence[str]) -> dict[str, NDArray[np.uint8] | NDArray[np.uint16]]:
    return {}
