"""Normative reference ranges for spatiotemporal gait parameters.

The defaults are broad bands for healthy adults walking at self-selected speed, each with
its literature source and the population that source studied (the report prints both,
so a band from older adults is not read as one for all adults). They are *not* age-,
sex- or height-matched; a lab that has its own reference data loads it with
:func:`load_normative_ranges` (JSON) and passes it to the report. Values are in SI units
(m, s, steps/min, % of gait cycle).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

from engine.errors import InputError


@dataclass(frozen=True)
class NormativeRange:
    """A reference band for one parameter.

    Attributes:
        parameter: key of the parameter (see ``engine.report.render.PARAMETERS``).
        low: lower bound, SI units.
        high: upper bound, SI units.
        population: who the band describes.
        source: citation a clinician can look up.
    """

    parameter: str
    low: float
    high: float
    population: str
    source: str


_PERRY = ("Perry J, Burnfield JM. Gait Analysis: Normal and Pathological Function, "
          "2nd ed. SLACK, 2010")
_BOHANNON = ("Bohannon RW, Williams Andrews A. Normal walking speed: a descriptive "
             "meta-analysis. Physiotherapy 2011;97(3):182-189")
_HOLLMAN = ("Hollman JH, McDade EM, Petersen RC. Normative spatiotemporal gait parameters "
            "in older adults. Gait Posture 2011;34(1):111-118")
_OWINGS = ("Owings TM, Grabiner MD. Step width variability, but not step length "
           "variability or step time variability, discriminates gait of healthy young and "
           "older adults during treadmill locomotion. J Biomech 2004;37(6):935-938")

# Hollman et al. measured 294 cognitively normal people over 70 (Mayo Clinic Study of
# Aging) on a 5.6 m GAITRite walkway; saying only "healthy adults" hid that.
_HOLLMAN_POP = "healthy adults over 70 y (GAITRite walkway)"

DEFAULT_NORMATIVE_RANGES: tuple[NormativeRange, ...] = (
    NormativeRange("walking_speed_m_s", 1.10, 1.50, "adults 20-79 y, comfortable speed",
                   _BOHANNON),
    NormativeRange("cadence_steps_min", 100.0, 125.0, "healthy adults", _PERRY),
    NormativeRange("step_length_m", 0.55, 0.80, _HOLLMAN_POP, _HOLLMAN),
    NormativeRange("stride_length_m", 1.10, 1.60, "healthy adults", _PERRY),
    NormativeRange("step_time_s", 0.48, 0.60, _HOLLMAN_POP, _HOLLMAN),
    NormativeRange("step_width_m", 0.05, 0.14,
                   "healthy young and older adults, treadmill walking", _OWINGS),
    NormativeRange("stance_pct", 58.0, 64.0, "healthy adults", _PERRY),
    NormativeRange("swing_pct", 36.0, 42.0, "healthy adults", _PERRY),
    NormativeRange("double_support_pct", 16.0, 26.0, "healthy adults", _PERRY),
)


def normative_lookup(
    ranges: tuple[NormativeRange, ...] | list[NormativeRange] = DEFAULT_NORMATIVE_RANGES,
) -> dict[str, NormativeRange]:
    """Index ranges by parameter key.

    Args:
        ranges: The ranges (default: the built-in ones).

    Returns:
        Parameter key -> its range (a later range of the same key wins).
    """
    return {r.parameter: r for r in ranges}


def load_normative_ranges(path: str | Path) -> list[NormativeRange]:
    """Read a JSON list of ranges (fields as in :class:`NormativeRange`).

    Args:
        path: A JSON file (as :func:`save_normative_ranges` writes).

    Returns:
        The ranges, in file order.

    Raises:
        InputError: the file is not a list of complete, consistent ranges.
    """
    try:
        raw = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise InputError(f"cannot read normative ranges from {path}: {exc}") from exc
    if not isinstance(raw, list):
        raise InputError("normative ranges file must hold a JSON list of objects")
    out: list[NormativeRange] = []
    for i, item in enumerate(raw):
        try:
            r = NormativeRange(str(item["parameter"]), float(item["low"]), float(item["high"]),
                               str(item.get("population", "")), str(item["source"]))
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"normative range #{i + 1} is incomplete or invalid: {exc}") from exc
        if r.low > r.high:
            raise InputError(f"normative range #{i + 1} ({r.parameter}): low > high")
        out.append(r)
    return out


def save_normative_ranges(ranges: list[NormativeRange], path: str | Path) -> None:
    """Write ranges as JSON (the format :func:`load_normative_ranges` reads).

    Args:
        ranges: The ranges.
        path: Destination file (overwritten).
    """
    Path(path).write_text(json.dumps([asdict(r) for r in ranges], indent=2), encoding="utf-8")


@dataclass(frozen=True)
class MdcValue:
    """A published minimal detectable change (95 %) of one parameter.

    Attributes:
        parameter: key of an ``engine.report.progress.PROGRESS_PARAMETERS`` entry.
        mdc: MDC95 in SI units (1.96 · √2 · SEM of the test–retest study).
        population: who was measured (a patient group's MDC is not a healthy adult's).
        source: citation with authors, year and journal.
    """

    parameter: str
    mdc: float
    population: str
    source: str


_STEFFEN = ("Steffen T, Seney M. Test-retest reliability and minimal detectable change on "
            "balance and ambulation tests, the 36-item short-form health survey, and the "
            "unified Parkinson disease rating scale in people with parkinsonism. Phys Ther "
            "2008;88(6):733-746")

#: Published MDC95 values used by default in "Change over sessions": only those checked
#: against their paper. Steffen & Seney retested 37 community-dwelling adults with
#: parkinsonism (mean age 71 y) one week apart: comfortable gait speed MDC95 0.18 m/s.
#: No cadence, step, stride or width MDC is given by default (none was verified).
DEFAULT_MDC_VALUES: tuple[MdcValue, ...] = (
    MdcValue("walking_speed_m_s", 0.18,
             "adults with parkinsonism, mean age 71 y, comfortable speed, retest after 1 week",
             _STEFFEN),
)
