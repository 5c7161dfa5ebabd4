"""The engine's refusals of a file that an option for files from other labs fixes give
their reason and advice in parts (``engine.errors.GaitrigError.reason``/``advice``, the
options as tokens), beside the unchanged ``gaitrig gait`` message. The web says them
from the parts: "Analyse a file" on the Reports page names the fields under "Options for
files from other labs" (:func:`app.api.routes.reports.form_say`), a reference upload the
file's fault alone (:func:`app.api.routes._reference.no_walk`). Each raise site given
parts is walked here: no command-line flag, documentation path or token reaches either
page, and the words are those the phrase mapping of the message said (the fallback, kept
for errors raised with a message only)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from app.api.routes._reference import no_walk
from app.api.routes.reports import FILE_OPTIONS, form_say, form_words
from engine.errors import OPTIONS, VERBS, GaitrigError
from engine.io.markers import (
    MarkerTrajectories,
    characteristic_length,
    detect_vertical_axis,
)
from engine.mocap import ankle_widths_by_side, feet_from_markers, load_feet
from tests.app.mocap_files import standing_trc, walk_skeleton_csv, walk_trc
from tests.app.test_upload_file_options import ambiguous_up_trc
from tests.engine.test_mocap_ankle_options import _markers, _walk


def _without(m: MarkerTrajectories, drop: set[str]) -> MarkerTrajectories:
    keep = [i for i, lab in enumerate(m.labels) if lab not in drop]
    return MarkerTrajectories(m.times, m.positions[:, keep], [m.labels[i] for i in keep],
                              m.rate, m.units, meta=dict(m.meta))


def _renamed(m: MarkerTrajectories, names: dict[str, str]) -> MarkerTrajectories:
    return MarkerTrajectories(m.times, m.positions, [names.get(x, x) for x in m.labels],
                              m.rate, m.units, meta=dict(m.meta))


def _reference_steps(path: Path) -> None:
    from app.server import analysis as an

    an.reference_steps(path)


def _cases(tmp: Path) -> dict[str, Callable[[], object]]:
    w = _walk()
    lateral = _markers(w, "#ANK", lateral=True)
    joints = _markers(w, "#_Ankle", lateral=True)
    nan = np.full((5, 2, 3), np.nan)
    two = _renamed(lateral, {"LANK": "A:LANK", "XL": "B:LANK"})
    empty = lateral.positions.copy()
    empty[:, [lateral.labels.index("LANK"), lateral.labels.index("LHEE")]] = np.nan
    csv = tmp / "skeleton.csv"
    csv.write_bytes(walk_skeleton_csv())
    up = ambiguous_up_trc(tmp / "up.trc")
    trc = walk_trc(tmp / "walk.trc")
    return {
        # engine/io/markers.py
        "units unknown": lambda: characteristic_length(nan, ["A", "B"]),
        "up from too few markers": lambda: detect_vertical_axis(nan, ["A", "B"]),
        "up ambiguous": lambda: load_feet(up),
        # engine/mocap.py
        "units wrong": lambda: load_feet(up, up="z", units="m"),
        "up contradicts": lambda: load_feet(trc, up="-z"),
        "ankle widths count": lambda: ankle_widths_by_side((0.06, 0.07, 0.08)),
        "ankle width not a number": lambda: ankle_widths_by_side(("abc",)),  # type: ignore[arg-type]
        "ankle width range": lambda: ankle_widths_by_side(0.2),
        "lateral and names": lambda: feet_from_markers(lateral, "XL", "XR",
                                                       ankle_markers="lateral"),
        "width and names": lambda: feet_from_markers(lateral, "XL", "XR", ankle_width_m=0.07),
        "joint and width": lambda: feet_from_markers(lateral, ankle_markers="joint",
                                                     ankle_width_m=0.07),
        "one foot marker": lambda: feet_from_markers(lateral, left="XL"),
        "two subjects": lambda: feet_from_markers(two),
        "empty markers": lambda: feet_from_markers(
            MarkerTrajectories(lateral.times, empty, lateral.labels, lateral.rate,
                               lateral.units)),
        "unnamed markers": lambda: feet_from_markers(
            _renamed(lateral, {x: f"M{i}" for i, x in enumerate(lateral.labels)})),
        "lateral without ankle markers": lambda: feet_from_markers(
            _without(lateral, {"LANK", "RANK"}), ankle_markers="lateral"),
        "width unused": lambda: feet_from_markers(joints, ankle_width_m=0.07),
        "lateral centre unplaced": lambda: feet_from_markers(
            _markers(w, "#_Ankle", lateral=True, feet=False), ankle_markers="lateral"),
        "lateral on a skeleton": lambda: load_feet(csv, ankle_markers="lateral"),
        "width on a skeleton": lambda: load_feet(csv, ankle_width_m=0.07),
        # engine/gait.py
        "no straight walking": lambda: _reference_steps(standing_trc(tmp / "still.trc")),
        "too few steps": lambda: _reference_steps(walk_trc(tmp / "short.trc", n_steps=2)),
    }


@pytest.fixture(scope="module")
def refused(tmp_path_factory: pytest.TempPathFactory) -> dict[str, GaitrigError]:
    out = {}
    for case, call in _cases(tmp_path_factory.mktemp("refused")).items():
        with pytest.raises(GaitrigError) as exc:
            call()
        out[case] = exc.value
    return out


NAMES = ["units unknown", "up from too few markers", "up ambiguous", "units wrong",
         "up contradicts", "ankle widths count", "ankle width not a number",
         "ankle width range", "lateral and names", "width and names", "joint and width",
         "one foot marker", "two subjects", "empty markers", "unnamed markers",
         "lateral without ankle markers", "width unused", "lateral centre unplaced",
         "lateral on a skeleton", "width on a skeleton", "no straight walking",
         "too few steps"]


def _clean(text: str) -> None:
    assert "--" not in text and "docs/" not in text, text
    assert "{" not in text and "}" not in text, text


@pytest.mark.parametrize("case", NAMES)
def test_analyse_a_file_says_the_fields(refused: dict[str, GaitrigError], case: str) -> None:
    """The page's words from the parts are those the phrase mapping gave the message."""
    exc = refused[case]
    assert exc.structured, str(exc)
    assert exc.option in ((None,) if case in ("no straight walking", "too few steps")
                          else OPTIONS), (case, exc.option)
    said = exc.words(form_say)
    assert said is not None
    _clean(said)
    assert said == form_words(str(exc)), (said, str(exc))


@pytest.mark.parametrize("case", NAMES)
def test_a_reference_says_the_files_fault(refused: dict[str, GaitrigError],
                                          case: str, tmp_path: Path) -> None:
    """A reference upload (no options) says what is wrong and what to do with the file,
    no option advice; as the phrase mapping did for the errors a reference can meet."""
    exc = refused[case]
    copy = tmp_path / "reference.trc"
    said = no_walk(exc, copy, "trial 3.trc")
    _clean(said)
    assert FILE_OPTIONS not in said and "sensors" not in said, said
    assert said.startswith("'trial 3.trc' has no walk"), said
    if exc.reason is not None and not any(f"{{{o}" in exc.reason for o in OPTIONS):
        # no option given: a reference can meet it, and was told so before
        assert said == no_walk(type(exc)(str(exc)), copy, "trial 3.trc"), said


def test_every_case_is_walked(refused: dict[str, GaitrigError]) -> None:
    assert sorted(refused) == sorted(NAMES)


def test_every_token_has_the_pages_words() -> None:
    """Whatever an engine error's advice names, the page says it without a flag."""
    for option in OPTIONS:
        for verb in VERBS:
            for value, example in ((None, None), ("x", "x")):
                words = form_say(option, value, verb, example)
                assert words and "--" not in words and "{" not in words, (option, verb)


def test_a_message_only_error_keeps_the_phrase_mapping() -> None:
    """An error raised without parts (a new site not yet given them) is still mapped."""
    exc = GaitrigError("cannot detect the vertical axis: too few markers; give it with --up")
    assert not exc.structured and exc.words(form_say) is None
    assert form_words(str(exc)).endswith(f"choose the vertical axis under '{FILE_OPTIONS}'")
