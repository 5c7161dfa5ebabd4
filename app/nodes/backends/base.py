"""The hardware-backend interface every node backend implements.

A backend owns one depth sensor. The agent calls :meth:`Backend.open` once, then
iterates :meth:`Backend.frames` in a worker thread (the iterator blocks until the sensor
delivers the next frame, so it paces the stream at the sensor's own rate), and calls
:meth:`Backend.close` on shutdown (from another thread: ``frames`` must then end).

A :class:`Frame` always carries the skeletons; images are produced lazily by
:meth:`Frame.images` because rendering or decoding them costs far more than tracking and
is only needed while recording images or when the server subscribed to them.

Conventions: ``t_local`` is the node's own clock in seconds (the server converts);
depth is ``uint16`` millimetres, body index ``uint8`` (255 = no body), colour ``uint8``
RGB; skeleton positions are metres in the sensor's (OpenCV) frame.
"""

from __future__ import annotations

import logging
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.nodes.protocol import CameraLens, SensorInfo, SensorLens

log = logging.getLogger("gaitrig.node")

#: A frame this late against its capture (or recorded) instant means the computer cannot
#: keep up: the simulator and the replay say so (:meth:`Backend.warn`), at most every
#: :data:`LATE_WARN_EVERY_S`, and not in their first minute (starting up is slow anyway).
LATE_WARN_S = 0.5
LATE_WARN_EVERY_S = 60.0

ImageFn = Callable[[Sequence[str]], dict[str, NDArray[np.uint8] | NDArray[np.uint16]]]
#: ``preview(streams, scale)``: the images already downscaled by ``scale`` (< 1).
PreviewFn = Callable[[Sequence[str], float], dict[str, NDArray[np.uint8] | NDArray[np.uint16]]]


def _no_images(streams: Sequence[str]) -> dict[str, NDArray[np.uint8] | NDArray[np.uint16]]:
    return {}


def downscale_image(stream: str, img: NDArray[Any], scale: float) -> NDArray[Any]:
    """Resize one image by ``scale`` as every image leaving a node is: colour by area
    averaging, depth and body index by nearest neighbour (no invented depths or labels)."""
    import cv2  # only nodes that send images need OpenCV

    if scale == 1.0:
        return img
    h, w = img.shape[:2]
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    interp = cv2.INTER_AREA if stream == "color" else cv2.INTER_NEAREST
    return np.asarray(cv2.resize(img, size, interpolation=interp))


@dataclass
class Frame:
    """One capture of a sensor.

    Attributes:
        t_local: capture time on the node's clock (s).
        positions: ``(B, J, 3)`` float32 joint positions, metres, sensor frame.
        states: ``(B, J)`` uint8 :class:`engine.skeleton.TrackingState` values.
        body_ids: ``B`` tracking ids.
        images: ``images(streams)`` → ``{"depth"|"color"|"body_index": array}``.
        preview: optional ``preview(streams, scale)`` → the same images at ``scale`` of the
            full size (nearest-neighbour geometry for depth/body index), for backends that
            make small live previews much cheaper than full images (the simulator renders
            them directly); ``None``: the agent downscales ``images``. Recordings always use
            ``images``.
    """

    t_local: float
    positions: NDArray[np.float32]
    states: NDArray[np.uint8]
    body_ids: list[int] = field(default_factory=list)
    images: ImageFn = _no_images
    preview: PreviewFn | None = None


class Backend(ABC):
    """A depth sensor as seen by the node agent (see the module docstring)."""

    name: str = "base"
    #: Set by the node agent: carries a warning on to the server (any thread may call it).
    warning_sink: Callable[[str], None] | None = None
    #: OpenCV lens distortion (k1, k2, p1, p2[, k3[, k4, k5, k6]]) of the colour/depth
    #: images the backend gives (at ``SensorInfo.color_K``/``depth_K``), known after
    #: :meth:`open`; None = none (an ideal or rectified lens). Sent with each calibration
    #: frame and announced after the welcome (:meth:`sensor_lens`), not in the ``hello``:
    #: a server older than the node refuses unknown sensor fields but ignores unknown
    #: ``calib`` header keys.
    color_dist: list[float] | None = None
    depth_dist: list[float] | None = None
    #: Where those lenses come from, in plain words for the Rig page.
    lens_source: str = "reported by the sensor"

    @abstractmethod
    def open(self) -> SensorInfo:
        """Start the device; returns what the sensor is (sizes, intrinsics, rate)."""

    @abstractmethod
    def frames(self) -> Iterator[Frame]:
        """Blocking iterator of frames at the sensor's rate; ends after :meth:`close`."""

    @abstractmethod
    def now(self) -> float:
        """The node's local clock (same clock as ``Frame.t_local``)."""

    def close(self) -> None:  # noqa: B027 - optional hook
        """Stop the device (called from another thread; ``frames`` must end)."""

    def warn(self, text: str) -> None:
        """Report a problem found after :meth:`open` (body tracking stopped, an unreliable
        clock, frames dropped): the node's log, and the server's Rig page beside this node
        (the agent sends it as a ``warning`` message, coalesced and rate-limited).
        Problems found by :meth:`open` go in ``SensorInfo.warnings`` instead. Any thread.

        Args:
            text: plain words for the person at the Rig page, saying what to do.
        """
        log.warning("%s", text)
        sink = self.warning_sink
        if sink is not None:
            sink(text)

    def sensor_lens(self, info: SensorInfo) -> SensorLens | None:
        """The ``sensor_lens`` message announcing the cameras of ``info`` (what
        :meth:`open` returned) with their lenses: each camera whose intrinsics are known,
        with :attr:`depth_dist`/:attr:`color_dist` (none: an ideal lens). None when no
        camera's intrinsics are known (a replay: recordings keep no camera model)."""
        def camera(size: tuple[int, int], K: list[list[float]] | None,
                   dist: list[float] | None) -> CameraLens | None:
            return None if K is None else CameraLens(size=size, K=K, dist=list(dist or []))

        depth = camera(info.depth_size, info.depth_K, self.depth_dist)
        color = camera(info.color_size, info.color_K, self.color_dist)
        if depth is None and color is None:
            return None
        return SensorLens(source=self.lens_source, depth=depth, color=color)

    def diagnostics(self, t_host: float) -> dict[str, float]:
        """Test-only truths (e.g. the simulator's true clock offset); empty for hardware."""
        return {}
