"""Skeleton joint sets, tracking states, bone hierarchy and the skeleton time series.

Joint names follow each vendor's SDK (Kinect v2 names are the project's canonical
ones, e.g. ``SpineBase``, ``AnkleLeft``). Tracking states use the Kinect SDK values.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from engine.errors import InputError


class TrackingState(IntEnum):
    """Per-joint tracking state, numerically identical to the Kinect SDK's."""

    NOT_TRACKED = 0
    INFERRED = 1
    TRACKED = 2


KINECT_V2_JOINTS: tuple[str, ...] = (
    "SpineBase", "SpineMid", "Neck", "Head",
    "ShoulderLeft", "ElbowLeft", "WristLeft", "HandLeft",
    "ShoulderRight", "ElbowRight", "WristRight", "HandRight",
    "HipLeft", "KneeLeft", "AnkleLeft", "FootLeft",
    "HipRight", "KneeRight", "AnkleRight", "FootRight",
    "SpineShoulder", "HandTipLeft", "ThumbLeft", "HandTipRight", "ThumbRight",
)

KINECT_V2_PARENTS: dict[str, str | None] = {
    "SpineBase": None, "SpineMid": "SpineBase", "SpineShoulder": "SpineMid",
    "Neck": "SpineShoulder", "Head": "Neck",
    "ShoulderLeft": "SpineShoulder", "ElbowLeft": "ShoulderLeft", "WristLeft": "ElbowLeft",
    "HandLeft": "WristLeft", "HandTipLeft": "HandLeft", "ThumbLeft": "WristLeft",
    "ShoulderRight": "SpineShoulder", "ElbowRight": "ShoulderRight",
    "WristRight": "ElbowRight", "HandRight": "WristRight", "HandTipRight": "HandRight",
    "ThumbRight": "WristRight",
    "HipLeft": "SpineBase", "KneeLeft": "HipLeft", "AnkleLeft": "KneeLeft",
    "FootLeft": "AnkleLeft",
    "HipRight": "SpineBase", "KneeRight": "HipRight", "AnkleRight": "KneeRight",
    "FootRight": "AnkleRight",
}

KINECT_V1_JOINTS: tuple[str, ...] = (
    "HipCenter", "Spine", "ShoulderCenter", "Head",
    "ShoulderLeft", "ElbowLeft", "WristLeft", "HandLeft",
    "ShoulderRight", "ElbowRight", "WristRight", "HandRight",
    "HipLeft", "KneeLeft", "AnkleLeft", "FootLeft",
    "HipRight", "KneeRight", "AnkleRight", "FootRight",
)

KINECT_V1_PARENTS: dict[str, str | None] = {
    "HipCenter": None, "Spine": "HipCenter", "ShoulderCenter": "Spine",
    "Head": "ShoulderCenter",
    "ShoulderLeft": "ShoulderCenter", "ElbowLeft": "ShoulderLeft", "WristLeft": "ElbowLeft",
    "HandLeft": "WristLeft",
    "ShoulderRight": "ShoulderCenter", "ElbowRight": "ShoulderRight",
    "WristRight": "ElbowRight", "HandRight": "WristRight",
    "HipLeft": "HipCenter", "KneeLeft": "HipLeft", "AnkleLeft": "KneeLeft",
    "FootLeft": "AnkleLeft",
    "HipRight": "HipCenter", "KneeRight": "HipRight", "AnkleRight": "KneeRight",
    "FootRight": "AnkleRight",
}

AZURE_KINECT_JOINTS: tuple[str, ...] = (
    "PELVIS", "SPINE_NAVEL", "SPINE_CHEST", "NECK",
    "CLAVICLE_LEFT", "SHOULDER_LEFT", "ELBOW_LEFT", "WRIST_LEFT", "HAND_LEFT",
    "HANDTIP_LEFT", "THUMB_LEFT",
    "CLAVICLE_RIGHT", "SHOULDER_RIGHT", "ELBOW_RIGHT", "WRIST_RIGHT", "HAND_RIGHT",
    "HANDTIP_RIGHT", "THUMB_RIGHT",
    "HIP_LEFT", "KNEE_LEFT", "ANKLE_LEFT", "FOOT_LEFT",
    "HIP_RIGHT", "KNEE_RIGHT", "ANKLE_RIGHT", "FOOT_RIGHT",
    "HEAD", "NOSE", "EYE_LEFT", "EAR_LEFT", "EYE_RIGHT", "EAR_RIGHT",
)

AZURE_KINECT_PARENTS: dict[str, str | None] = {
    "PELVIS": None, "SPINE_NAVEL": "PELVIS", "SPINE_CHEST": "SPINE_NAVEL",
    "NECK": "SPINE_CHEST",
    "CLAVICLE_LEFT": "SPINE_CHEST", "SHOULDER_LEFT": "CLAVICLE_LEFT",
    "ELBOW_LEFT": "SHOULDER_LEFT", "WRIST_LEFT": "ELBOW_LEFT", "HAND_LEFT": "WRIST_LEFT",
    "HANDTIP_LEFT": "HAND_LEFT", "THUMB_LEFT": "WRIST_LEFT",
    "CLAVICLE_RIGHT": "SPINE_CHEST", "SHOULDER_RIGHT": "CLAVICLE_RIGHT",
    "ELBOW_RIGHT": "SHOULDER_RIGHT", "WRIST_RIGHT": "ELBOW_RIGHT",
    "HAND_RIGHT": "WRIST_RIGHT", "HANDTIP_RIGHT": "HAND_RIGHT", "THUMB_RIGHT": "WRIST_RIGHT",
    "HIP_LEFT": "PELVIS", "KNEE_LEFT": "HIP_LEFT", "ANKLE_LEFT": "KNEE_LEFT",
    "FOOT_LEFT": "ANKLE_LEFT",
    "HIP_RIGHT": "PELVIS", "KNEE_RIGHT": "HIP_RIGHT", "ANKLE_RIGHT": "KNEE_RIGHT",
    "FOOT_RIGHT": "ANKLE_RIGHT",
    "HEAD": "NECK", "NOSE": "HEAD", "EYE_LEFT": "HEAD", "EAR_LEFT": "HEAD",
    "EYE_RIGHT": "HEAD", "EAR_RIGHT": "HEAD",
}


@dataclass(frozen=True)
class JointSet:
    """A named joint set with its bone hierarchy and semantic roles."""

    name: str
    joints: tuple[str, ...]
    parents: dict[str, str | None]
    #: semantic role -> joint name, so algorithms need not know vendor spellings.
    roles: dict[str, str]

    def index(self, joint: str) -> int:
        """Position of ``joint`` in :attr:`joints` (the joint axis of a series' arrays).

        Args:
            joint: SDK joint name (e.g. ``"AnkleLeft"``).

        Returns:
            Its index.

        Raises:
            InputError: the joint is not in this joint set.
        """
        try:
            return self.joints.index(joint)
        except ValueError:
            raise InputError(f"joint {joint!r} is not in the {self.name} joint set") from None

    def role_index(self, role: str) -> int:
        """Position of the joint playing ``role`` (a key of :attr:`roles`, e.g. ``"ankle_left"``).

        Args:
            role: Semantic role (``pelvis``, ``head``, ``knee_left`` ...).

        Returns:
            Index of that joint on the joint axis.

        Raises:
            KeyError: this joint set has no joint for that role.
            InputError: the role's joint is not in the set (an inconsistent joint set).
        """
        return self.index(self.roles[role])

    @property
    def bones(self) -> list[tuple[str, str]]:
        """(parent, child) pairs in joint order."""
        return [(p, j) for j, p in self.parents.items() if p is not None]

    @property
    def parent_indices(self) -> NDArray[np.int64]:
        """Index of each joint's parent (−1 for the root), in joint order."""
        return np.array(
            [-1 if self.parents[j] is None else self.joints.index(self.parents[j])  # type: ignore[arg-type]
             for j in self.joints]
        )


def _roles(
    pelvis: str, spine_mid: str, spine_top: str, neck: str, head: str, side: str
) -> dict[str, str]:
    r = {"pelvis": pelvis, "spine_mid": spine_mid, "spine_top": spine_top, "neck": neck,
         "head": head}
    for s, S in (("left", "Left"), ("right", "Right")):
        for part in ("Shoulder", "Elbow", "Wrist", "Hand", "Hip", "Knee", "Ankle", "Foot"):
            if side == "camel":
                r[f"{part.lower()}_{s}"] = f"{part}{S}"
            else:
                r[f"{part.lower()}_{s}"] = f"{part.upper()}_{S.upper()}"
    return r


KINECT_V2 = JointSet("kinect_v2", KINECT_V2_JOINTS, KINECT_V2_PARENTS,
                     _roles("SpineBase", "SpineMid", "SpineShoulder", "Neck", "Head", "camel"))
KINECT_V1 = JointSet("kinect_v1", KINECT_V1_JOINTS, KINECT_V1_PARENTS,
                     _roles("HipCenter", "Spine", "ShoulderCenter", "ShoulderCenter", "Head",
                            "camel"))
AZURE_KINECT = JointSet("azure_kinect", AZURE_KINECT_JOINTS, AZURE_KINECT_PARENTS,
                        _roles("PELVIS", "SPINE_NAVEL", "SPINE_CHEST", "NECK", "HEAD", "upper"))

JOINT_SETS: dict[str, JointSet] = {js.name: js for js in (KINECT_V2, KINECT_V1, AZURE_KINECT)}


def joint_set_for(names: ArrayLike | list[str] | tuple[str, ...]) -> JointSet:
    """The joint set whose names equal ``names`` (in order).

    Args:
        names: Joint names in file order (Kinect v1, Kinect v2 or Azure Kinect SDK
            spellings).

    Returns:
        The matching :class:`JointSet` of :data:`JOINT_SETS`.

    Raises:
        InputError: no joint set has exactly these names in this order.
    """
    names_t = tuple(str(n) for n in names)  # type: ignore[union-attr]
    for js in JOINT_SETS.values():
        if names_t == js.joints:
            return js
    raise InputError(
        f"unknown joint set with {len(names_t)} joints; expected Kinect v1 (20), "
        "Kinect v2 (25) or Azure Kinect (32) SDK joint names"
    )


@dataclass
class SkeletonSeries:
    """One body's skeleton over time.

    Attributes:
        times: ``(T,)`` seconds, strictly increasing.
        positions: ``(T, J, 3)`` metres; NaN where a joint has no estimate.
        states: ``(T, J)`` uint8 :class:`TrackingState` values.
        joint_set: the joint set the ``J`` axis follows.
        meta: free-form provenance (sensor id, frame, units, ...).
    """

    times: NDArray[np.float64]
    positions: NDArray[np.float64]
    states: NDArray[np.uint8]
    joint_set: JointSet = KINECT_V2
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.times = np.asarray(self.times, dtype=float)
        self.positions = np.asarray(self.positions, dtype=float)
        self.states = np.asarray(self.states, dtype=np.uint8)
        T = len(self.times)
        J = len(self.joint_set.joints)
        if self.positions.shape != (T, J, 3):
            raise InputError(
                f"positions must have shape ({T}, {J}, 3) for {self.joint_set.name}, "
                f"got {self.positions.shape}"
            )
        if self.states.shape != (T, J):
            raise InputError(f"states must have shape ({T}, {J}), got {self.states.shape}")
        if T > 1 and not np.all(np.diff(self.times) > 0):
            raise InputError("skeleton times must be strictly increasing")

    def __len__(self) -> int:
        return len(self.times)

    def __repr__(self) -> str:
        # A notebook shows the object: its shape and span, not the arrays.
        T = len(self.times)
        span = f"{self.times[0]:.2f}–{self.times[-1]:.2f} s" if T else "empty"
        rate = f", {(T - 1) / (self.times[-1] - self.times[0]):.4g} Hz" if T > 1 else ""
        tracked = (100.0 * float(np.mean(self.states == TrackingState.TRACKED))
                   if self.states.size else 0.0)
        return (f"SkeletonSeries({self.joint_set.name}, {T} frames, {span}{rate}, "
                f"{tracked:.0f} % of joints tracked, meta={self.meta})")

    def to_columns(self, with_states: bool = True) -> dict[str, NDArray[Any]]:
        """The series as named columns: ``time`` (s), ``<Joint>_x/_y/_z`` (m, NaN where a
        joint has no estimate) and ``<Joint>_state`` (:class:`TrackingState` values).

        The columns and their order are those of the skeleton CSV
        (:func:`engine.io.csv.write_skeleton_csv`), so ``pandas.DataFrame(s.to_columns())``
        is the table that file holds. The arrays are copies.

        Args:
            with_states: Include the ``<Joint>_state`` columns.

        Returns:
            Column name -> ``(T,)`` array.
        """
        cols: dict[str, NDArray[Any]] = {"time": self.times.copy()}
        for k, j in enumerate(self.joint_set.joints):
            for a, axis in enumerate("xyz"):
                cols[f"{j}_{axis}"] = self.positions[:, k, a].copy()
            if with_states:
                cols[f"{j}_state"] = self.states[:, k].copy()
        return cols

    def joint(self, name: str) -> NDArray[np.float64]:
        """``(T, 3)`` trajectory of one joint (m, the series' frame).

        Args:
            name: Joint name of the series' joint set (e.g. ``"AnkleLeft"``).

        Returns:
            A view into ``positions``.

        Raises:
            InputError: the joint is not in the joint set.
        """
        return self.positions[:, self.joint_set.index(name)]

    def tracked_positions(self) -> NDArray[np.float64]:
        """Positions with every joint that is not TRACKED set to NaN.

        Returns:
            A ``(T, J, 3)`` copy of the positions (m).
        """
        p = self.positions.copy()
        p[self.states != TrackingState.TRACKED] = np.nan
        return p

    def slice_time(self, t0: float, t1: float) -> SkeletonSeries:
        """The frames with ``t0 ≤ time ≤ t1`` (s, the series' own clock), as a new series.

        Args:
            t0: First time kept, s.
            t1: Last time kept, s.

        Returns:
            A series sharing the joint set, with a copy of ``meta``.
        """
        m = (self.times >= t0) & (self.times <= t1)
        return SkeletonSeries(self.times[m], self.positions[m], self.states[m], self.joint_set,
                              dict(self.meta))
