"""Options shared by the commands that read mocap files (``gaitrig gait``, ``gaitrig report``,
``gaitrig agreement``).

``--left``/``--right`` the foot markers; ``--up`` takes a negative axis as its value
(``--up -y``), which argparse alone would read as an option of its own; ``--units`` the
file's length unit in any case; ``--ankle-markers`` and ``--ankle-width-mm`` how the
ankle markers are taken.
"""

from __future__ import annotations

import argparse
from typing import Any

#: The vertical axes ``--up`` takes.
AXES = ("x", "y", "z", "-x", "-y", "-z")
#: ``--up`` given without an axis (yet: a negative axis follows as its own word).
AXIS_PENDING = "?"


class _Up(argparse.Action):
    """``--up AXIS``, or ``--up`` alone, waiting for the :class:`_NegativeAxis` after it
    (choices checked here: argparse would check the waiting mark against them)."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:
        # "Y", "+y" are y (the file headers and other tools write axes so)
        axis = None if values is None else str(values).strip().lower().removeprefix("+")
        if axis is not None and axis not in AXES:
            parser.error(f"argument --up: invalid choice: {values!r} (choose from "
                         f"{', '.join(AXES)})")
        setattr(namespace, self.dest, AXIS_PENDING if axis is None else axis)


class _NegativeAxis(argparse.Action):
    """The ``-x``/``-y``/``-z`` right after ``--up`` (``--up -y``), which argparse parses
    as an option; anywhere else it is an error that names the spelling to use."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:
        if getattr(namespace, self.dest, None) != AXIS_PENDING:
            parser.error(f"unrecognized argument {option_string}: for a vertical axis "
                         f"pointing down write --up {option_string}")
        setattr(namespace, self.dest, option_string)


def add_marker_arguments(parser: argparse.ArgumentParser, left_help: str,
                         right_help: str) -> None:
    """Register ``--left NAME`` and ``--right NAME`` (the foot markers to analyse).

    Args:
        parser: The command's parser.
        left_help: The help line of ``--left``.
        right_help: The help line of ``--right``.
    """
    parser.add_argument("--left", metavar="NAME", help=left_help)
    parser.add_argument("--right", metavar="NAME", help=right_help)


def add_up_argument(parser: argparse.ArgumentParser, help_text: str) -> None:
    """Register ``--up AXIS`` (``x``, ``y``, ``z``, ``-x``, ``-y``, ``-z``, any case).

    Args:
        parser: The command's parser.
        help_text: The option's help line.
    """
    parser.add_argument("--up", nargs="?", action=_Up, metavar="{" + ",".join(AXES) + "}",
                        help=help_text)
    # argparse reads the "-y" of "--up -y" as an option of its own, not as --up's value:
    # so it is one (hidden), which hands its axis to the --up just before it
    for axis in ("x", "y", "z"):
        parser.add_argument(f"-{axis}", dest="up", nargs=0, action=_NegativeAxis,
                            help=argparse.SUPPRESS)


def add_units_argument(parser: argparse.ArgumentParser, help_text: str) -> None:
    """Register ``--units {mm,cm,m}`` (any case).

    Args:
        parser: The command's parser.
        help_text: The option's help line.
    """
    parser.add_argument("--units", choices=["mm", "cm", "m"], type=str.lower, help=help_text)


def up_axis_missing(command: str, args: argparse.Namespace) -> str | None:
    """The error line when ``--up`` was given without an axis, else None.

    Args:
        command: The command's name, e.g. ``"gait"``.
        args: The parsed arguments.

    Returns:
        The message to print on stderr (exit code 2), or None when ``--up`` is fine.
    """
    if getattr(args, "up", None) != AXIS_PENDING:
        return None
    return f"gaitrig {command}: error: --up needs an axis: one of {', '.join(AXES)}"


def _widths_mm(text: str) -> tuple[float, ...]:
    """``--ankle-width-mm L[,R]``: one or two numbers in mm (the range is the engine's)."""
    parts = [p.strip() for p in text.split(",")]
    try:
        vals = tuple(float(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a width in mm: give one number for both feet or left,right, "
            "e.g. 70 or 68,72") from None
    if len(vals) > 2:
        raise argparse.ArgumentTypeError(
            f"{text!r} gives {len(vals)} widths: give one for both feet or two, left,right")
    return vals


def add_ankle_arguments(parser: argparse.ArgumentParser) -> None:
    """Register ``--ankle-markers auto|lateral|joint`` and ``--ankle-width-mm L[,R]``.

    Args:
        parser: The command's parser.
    """
    parser.add_argument("--ankle-markers", choices=["auto", "lateral", "joint"],
                        type=str.lower, default="auto",
                        help="auto: ankle markers named like LANK are on the lateral "
                             "malleolus (their joint centre estimated), L_Ankle/AnkleLeft "
                             "are joint centres; lateral: all are on the lateral malleolus; "
                             "joint: all are joint centres (measured as they are)")
    parser.add_argument("--ankle-width-mm", type=_widths_mm, metavar="L[,R]",
                        help="ankle width across the malleoli in mm, one for both feet or "
                             "left,right (40-150), instead of the C3D's PROCESSING widths "
                             "or the 70 mm population default")


def ankle_width_m(args: argparse.Namespace) -> tuple[float, ...] | None:
    """``--ankle-width-mm`` in metres (None when not given).

    Args:
        args: The parsed arguments.

    Returns:
        One or two widths, m.
    """
    mm = getattr(args, "ankle_width_mm", None)
    return None if mm is None else tuple(v / 1000.0 for v in mm)
