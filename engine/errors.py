"""Typed exceptions raised by the engine.

Every error that a user can cause (bad file, too little data, unreachable sensor)
raises a subclass of :class:`GaitrigError` whose message says what to fix. The API
maps these to HTTP 4xx responses.
"""

from __future__ import annotations


class GaitrigError(Exception):
    """Base class of every user-facing engine error."""


class InputError(GaitrigError, ValueError):
    """Input data is malformed, inconsistent or has the wrong units."""


class InsufficientDataError(GaitrigError):
    """There is not enough usable data for the requested analysis."""


class CalibrationError(GaitrigError):
    """Spatial calibration cannot be computed (e.g. a sensor cannot reach marker 1).

    Attributes:
        unreachable: Sensor ids with no path to the origin marker (may be empty).
    """

    def __init__(self, message: str, unreachable: list[str] | None = None) -> None:
        super().__init__(message)
        self.unreachable: list[str] = list(unreachable or [])
