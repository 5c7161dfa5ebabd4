"""3D view of a KSCC session: both users in the universal frame, side by side and overlaid.

The universal frame (origin at a user's initial centre, +X their initial facing, Z up) is
placed at ``origin`` in the lab scene so it does not overlap the rig. Three groups hang
below ``/kscc``: ``side/a`` and ``side/b`` (shifted ±``spacing_m`` along Y, side by side),
and ``overlay`` (both at the same spot, 2.5 m further along +X) — after calibration the
overlaid skeletons coincide when the two users do the same thing.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from engine.skeleton import JointSet, TrackingState

if TYPE_CHECKING:  # viser is needed only with the 3D view on (the Viewer loads it)
    import viser

SIDE_COLORS: dict[str, tuple[int, int, int]] = {"a": (11, 92, 173), "b": (207, 34, 46)}


def _segments(pos: NDArray[np.floating], states: NDArray[np.integer], js: JointSet
              ) -> NDArray[np.float32]:
    ok = np.isfinite(pos).all(axis=-1) & (np.asarray(states) > TrackingState.NOT_TRACKED)
    segs = [(pos[p], pos[j]) for j, p in enumerate(js.parent_indices) if p >= 0 and ok[j]
            and ok[p]]
    return np.asarray(segs, dtype=np.float32).reshape(-1, 2, 3)


def populate_kscc(server: viser.ViserServer,
                  skeletons: Mapping[str, tuple[NDArray[np.floating], NDArray[np.integer],
                                                JointSet] | None],
                  labels: Mapping[str, str] | None = None,
                  origin: tuple[float, float, float] = (0.0, -4.0, 0.0),
                  spacing_m: float = 0.8) -> None:
    """Draw (or clear) the two users of a KSCC session.

    Args:
        server: the viser server.
        skeletons: side (``a``/``b``) -> ``(positions (J, 3) universal frame, states (J,),
            joint set)``, or ``None`` while that side is not calibrated.
        labels: side -> text shown above it (e.g. the source).
        origin: where the universal frame sits in the lab scene (m).
        spacing_m: half distance between the side-by-side users.
    """
    server.scene.add_frame("/kscc", position=origin, axes_length=0.3, axes_radius=0.01)
    server.scene.add_label("/kscc/title", "KSCC universal frame", position=(0.0, 0.0, 2.2))
    shift = {"a": np.array([0.0, spacing_m, 0.0]), "b": np.array([0.0, -spacing_m, 0.0])}
    overlay = np.array([2.5, 0.0, 0.0])
    server.scene.add_label("/kscc/overlay_label", "overlay", position=(2.5, 0.0, 2.2))
    for side in ("a", "b"):
        item = skeletons.get(side)
        if item is None:
            server.scene.remove_by_name(f"/kscc/side/{side}")
            server.scene.remove_by_name(f"/kscc/overlay/{side}")
            continue
        pos, st, js = item
        segs = _segments(np.asarray(pos, dtype=float), st, js)
        if not len(segs):
            continue
        color = np.array(SIDE_COLORS.get(side, (90, 90, 90)), dtype=np.uint8)
        cols = np.broadcast_to(color, segs.shape).copy()
        server.scene.add_line_segments(f"/kscc/side/{side}", segs + shift[side].astype(np.float32),
                                       cols, thickness=0.02)
        server.scene.add_line_segments(f"/kscc/overlay/{side}", segs + overlay.astype(np.float32),
                                       cols, thickness=0.02)
        text = (labels or {}).get(side, side)
        server.scene.add_label(f"/kscc/side/{side}/label", text,
                               position=tuple(shift[side] + np.array([0.0, 0.0, 2.0])))
