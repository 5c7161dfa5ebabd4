"""The engine's refusals of a file that an option for files from other labs fixes are
raised in parts (``engine.errors.GaitrigError.reason``/``advice``, the options as tokens)
and said by each front end from them: ``gaitrig gait``'s message (``str(exc)``) by
:func:`engine.errors.cli_say` (the flags), "Analyse a file" on the Reports page by
:func:`app.api.routes.reports.form_say` (the fields under "Options for files from other
labs"), a reference upload by :func:`app.api.routes._reference.no_walk` (the file's fault
alone). Each raise site given parts is walked here and its words pinned on all three; no
command-line flag, documentation path or token reaches either page. An error raised with
its message only names no option (checked in the engine's sources) and is said as it is.
"""

from __future__ import annotations

import ast
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from app.api.routes._reference import WHAT_TO_DO, no_walk
from app.api.routes.reports import FILE_OPTIONS, form_say
from engine.errors import FLAGS, OPTIONS, VERBS, GaitrigError, InputError, cli_say
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
        "ankle markers value": lambda: feet_from_markers(lateral, ankle_markers="inner"),
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


CLI = {
    "units unknown":
        "cannot guess the length unit: no frame with two or more markers; give the units "
        "explicitly",
    "up from too few markers":
        "cannot detect the vertical axis: too few markers; give it with --up",
    "up ambiguous":
        "cannot tell the vertical axis from the foot markers (x or z: the feet stand at one "
        "level along both); give it with --up, e.g. --up x",
    "units wrong":
        "with --units m the body measures 819 m (leg length or height); fix --units or leave "
        "it out",
    "up contradicts":
        "--up -z contradicts the markers: the pelvis/head are above the feet along z; give "
        "--up z or leave it out",
    "ankle widths count":
        "3 ankle widths given; give the distance across the malleoli in millimetres, one value "
        "for both feet or left,right: --ankle-width-mm 70 or --ankle-width-mm 68,72",
    "ankle width not a number":
        "ankle width ['abc'] is not a number; give the distance across the malleoli in "
        "millimetres, one value for both feet or left,right: --ankle-width-mm 70 or "
        "--ankle-width-mm 68,72",
    "ankle width range":
        "an ankle width of 200 mm (both feet) is outside 40-150 mm (adult ankles measure about "
        "55-90 mm); give the distance across the malleoli in millimetres, one value for both "
        "feet or left,right: --ankle-width-mm 70 or --ankle-width-mm 68,72",
    "lateral and names":
        "--ankle-markers lateral applies to the ankle markers found by name; with "
        "--left/--right given, the named markers are measured as they are: leave "
        "--ankle-markers lateral out, or leave --left/--right out to have the ankle joint "
        "centres estimated",
    "width and names":
        "--ankle-width-mm applies to the ankle markers found by name; with --left/--right "
        "given, the named markers are measured as they are: leave --ankle-width-mm out, or "
        "leave --left/--right out to have the ankle joint centres estimated",
    "joint and width":
        "--ankle-width-mm places joint centres from lateral-malleolus markers; with "
        "--ankle-markers joint the markers are the joint centres: leave one of the two out",
    "ankle markers value":
        "--ankle-markers 'inner' is not one of auto, lateral, joint",
    "one foot marker":
        "give both --left and --right marker names, or neither",
    "two subjects":
        "several markers are named like 'A:LANK': A:LANK, B:LANK; choose one subject's feet "
        "with --left/--right, e.g. --left A:LANK",
    "empty markers":
        "no usable left ankle or heel marker: LANK, LHEE hold no data (missing in every frame "
        "but at most one); name other foot markers with --left/--right",
    "unnamed markers":
        "no usable left ankle or heel and no right ankle or heel marker (looked for names like "
        "LANK/RANK, LHEE/RHEE, L.Ankle, L_FAL, L_FCC, AnkleLeft: docs/gait-json.md lists "
        "them); available labels: M0, M1, M2, M3, M4, M5, M6, M7, M8, M9, M10, M11; name the "
        "foot markers with --left/--right",
    "lateral without ankle markers":
        "--ankle-markers lateral: the file has no ankle marker (looked for names like LANK, "
        "L_Ankle, L.Ankle.Lat, L_FAL); leave --ankle-markers out",
    "width unused":
        "--ankle-width-mm is not used: L_Ankle and R_Ankle are taken for ankle joint centres "
        "by name (or no ankle marker was found); give --ankle-markers lateral if they are on "
        "the lateral malleoli, or leave --ankle-width-mm out",
    "lateral centre unplaced":
        "--ankle-markers lateral: the left ankle joint centre cannot be placed from L_Ankle: "
        "the file has no medial malleolus marker and no heel and toe markers of that foot (its "
        "axis), nor the other foot's centre to place it across the walking direction; it needs "
        "that foot's heel and toe markers (named like LHEE, LTOE), or leave --ankle-markers "
        "out to measure L_Ankle as it is (with a note)",
    "lateral on a skeleton":
        "--ankle-markers lateral applies to marker files (.c3d, .trc); a skeleton CSV's ankles "
        "are joints: leave it out",
    "width on a skeleton":
        "--ankle-width-mm applies to marker files (.c3d, .trc); a skeleton CSV's ankles are "
        "joints: leave it out",
    "no straight walking":
        "no straight walking found (the body centre must travel ≥ 0.5 m at ≥ 0.15 m/s for ≥ "
        "0.8 s)",
    "too few steps":
        "only 0 steps found in 1 pass; at least two steps are needed. The longest stretch of "
        "straight walking seen was 1.1 m (0.8 s): record a longer walk, or, if the subject "
        "walked farther, place or add sensors to cover more of the walkway",
}
FORM = {
    "units unknown":
        "cannot guess the length unit: no frame with two or more markers; choose the units "
        "under 'Options for files from other labs'",
    "up from too few markers":
        "cannot detect the vertical axis: too few markers; choose the vertical axis under "
        "'Options for files from other labs'",
    "up ambiguous":
        "cannot tell the vertical axis from the foot markers (x or z: the feet stand at one "
        "level along both); choose the vertical axis under 'Options for files from other "
        "labs', e.g. X up",
    "units wrong":
        "with the units m the body measures 819 m (leg length or height); choose other units "
        "under 'Options for files from other labs', or Automatic",
    "up contradicts":
        "the vertical axis Z down contradicts the markers: the pelvis/head are above the feet "
        "along z; choose Z up as the vertical axis under 'Options for files from other labs', "
        "or Automatic",
    "ankle widths count":
        "3 ankle widths given; give the distance across the malleoli in millimetres, one value "
        "for both feet or left,right: 70 or 68,72",
    "ankle width not a number":
        "ankle width ['abc'] is not a number; give the distance across the malleoli in "
        "millimetres, one value for both feet or left,right: 70 or 68,72",
    "ankle width range":
        "an ankle width of 200 mm (both feet) is outside 40-150 mm (adult ankles measure about "
        "55-90 mm); give the distance across the malleoli in millimetres, one value for both "
        "feet or left,right: 70 or 68,72",
    "lateral and names":
        "ankle markers 'On the lateral malleoli' applies to the ankle markers found by name; "
        "with left and right foot markers given, the named markers are measured as they are: "
        "set the ankle markers to Automatic, or leave the left and right foot markers empty to "
        "have the ankle joint centres estimated",
    "width and names":
        "the ankle width applies to the ankle markers found by name; with left and right foot "
        "markers given, the named markers are measured as they are: leave the ankle width "
        "empty, or leave the left and right foot markers empty to have the ankle joint centres "
        "estimated",
    "joint and width":
        "the ankle width places joint centres from lateral-malleolus markers; with ankle "
        "markers 'At the ankle joint centres' the markers are the joint centres: leave one of "
        "the two out",
    "ankle markers value":
        "the ankle markers 'inner' is not one of auto, lateral, joint",
    "one foot marker":
        "give both the left and the right foot marker under 'Options for files from other "
        "labs', or neither",
    "two subjects":
        "several markers are named like 'A:LANK': A:LANK, B:LANK; choose one subject's feet by "
        "giving the left and right foot markers under 'Options for files from other labs', "
        "e.g. A:LANK as the left one",
    "empty markers":
        "no usable left ankle or heel marker: LANK, LHEE hold no data (missing in every frame "
        "but at most one); name other foot markers by giving the left and right foot markers "
        "under 'Options for files from other labs'",
    "unnamed markers":
        "no usable left ankle or heel and no right ankle or heel marker (markers named like "
        "LANK/RANK, LHEE/RHEE, L.Ankle, L_FAL, L_FCC, AnkleLeft are recognised); available "
        "labels: M0, M1, M2, M3, M4, M5, M6, M7, M8, M9, M10, M11; name the foot markers by "
        "giving the left and right foot markers under 'Options for files from other labs'",
    "lateral without ankle markers":
        "ankle markers 'On the lateral malleoli': the file has no ankle marker (looked for "
        "names like LANK, L_Ankle, L.Ankle.Lat, L_FAL); set the ankle markers to Automatic",
    "width unused":
        "the ankle width is not used: L_Ankle and R_Ankle are taken for ankle joint centres by "
        "name (or no ankle marker was found); give ankle markers 'On the lateral malleoli' if "
        "they are on the lateral malleoli, or leave the ankle width empty",
    "lateral centre unplaced":
        "ankle markers 'On the lateral malleoli': the left ankle joint centre cannot be placed "
        "from L_Ankle: the file has no medial malleolus marker and no heel and toe markers of "
        "that foot (its axis), nor the other foot's centre to place it across the walking "
        "direction; it needs that foot's heel and toe markers (named like LHEE, LTOE), or set "
        "the ankle markers to Automatic to measure L_Ankle as it is (with a note)",
    "lateral on a skeleton":
        "ankle markers 'On the lateral malleoli' applies to marker files (.c3d, .trc); a "
        "skeleton CSV's ankles are joints: leave it out",
    "width on a skeleton":
        "the ankle width applies to marker files (.c3d, .trc); a skeleton CSV's ankles are "
        "joints: leave it out",
    # messages that name no option read the same everywhere
    **{k: CLI[k] for k in ("no straight walking", "too few steps")},
}
REFERENCE = {
    "units unknown":
        "'trial 3.trc' has no walk the report can use: cannot guess the length unit: no frame "
        "with two or more markers",
    "up from too few markers":
        "'trial 3.trc' has no walk the report can use: cannot detect the vertical axis: too "
        "few markers",
    "up ambiguous":
        "'trial 3.trc' has no walk the report can use: cannot tell the vertical axis from the "
        "foot markers (x or z: the feet stand at one level along both)",
    "two subjects":
        "'trial 3.trc' has no walk the report can use: several markers are named like "
        "'A:LANK': A:LANK, B:LANK",
    "empty markers":
        "'trial 3.trc' has no walk the report can use: no usable left ankle or heel marker: "
        "LANK, LHEE hold no data (missing in every frame but at most one)",
    "unnamed markers":
        "'trial 3.trc' has no walk the report can use: no usable left ankle or heel and no "
        "right ankle or heel marker (markers named like LANK/RANK, LHEE/RHEE, L.Ankle, L_FAL, "
        "L_FCC, AnkleLeft are recognised); available labels: M0, M1, M2, M3, M4, M5, M6, M7, "
        "M8, M9, M10, M11",
    "no straight walking":
        "'trial 3.trc' has no walk in it: 0 steps found — no straight walking (the body centre "
        "must travel ≥ 0.5 m at ≥ 0.15 m/s for ≥ 0.8 s)",
    "too few steps":
        "'trial 3.trc' has no walk in it: only 0 steps found in 1 pass; at least two steps are "
        "needed",
}

NAMES = list(CLI)

#: The command line's own reason of a site: it points to its documentation of the names.
CLI_OWN = {"unnamed markers": ("markers named like {} are recognised",
                               "looked for names like {}: docs/gait-json.md lists them")}


def _clean(text: str) -> None:
    assert "--" not in text and "docs/" not in text, text
    assert "{" not in text and "}" not in text, text


@pytest.mark.parametrize("case", NAMES)
def test_the_cli_message_is_made_from_the_parts(refused: dict[str, GaitrigError],
                                                case: str) -> None:
    """``gaitrig gait``'s words are the parts said as flags, as the message written beside
    them said before (the one exception: a pointer to the documentation)."""
    exc = refused[case]
    assert exc.structured, str(exc)
    assert str(exc) == CLI[case]
    made = exc.words(cli_say)
    assert made is not None
    if case in CLI_OWN:
        names = "LANK/RANK, LHEE/RHEE, L.Ankle, L_FAL, L_FCC, AnkleLeft"
        page, own = (x.format(names) for x in CLI_OWN[case])
        assert page in made, made
        made = made.replace(page, own)
    assert made == str(exc)


@pytest.mark.parametrize("case", NAMES)
def test_analyse_a_file_says_the_fields(refused: dict[str, GaitrigError], case: str) -> None:
    """The page's words from the parts (those the phrase mapping of the message said
    before it was dropped)."""
    exc = refused[case]
    assert exc.option in ((None,) if case in ("no straight walking", "too few steps")
                          else OPTIONS), (case, exc.option)
    said = exc.words(form_say)
    assert said is not None
    _clean(said)
    assert said == FORM[case]


@pytest.mark.parametrize("case", NAMES)
def test_a_reference_says_the_files_fault(refused: dict[str, GaitrigError],
                                          case: str, tmp_path: Path) -> None:
    """A reference upload (no options) says what is wrong and what to do with the file,
    no option advice."""
    exc = refused[case]
    copy = tmp_path / "reference.trc"
    said = no_walk(exc, copy, "trial 3.trc")
    _clean(said)
    assert FILE_OPTIONS not in said and "sensors" not in said, said
    assert said.startswith("'trial 3.trc' has no walk"), said
    if case in REFERENCE:  # no option given: a reference can meet it
        assert said == f"{REFERENCE[case]}. {WHAT_TO_DO}"


def test_every_case_is_walked(refused: dict[str, GaitrigError]) -> None:
    assert sorted(refused) == sorted(NAMES) == sorted(FORM)


def test_every_token_has_the_pages_words() -> None:
    """Whatever an engine error's advice names, the page says it without a flag."""
    for option in OPTIONS:
        for verb in VERBS:
            for value, example in ((None, None), ("x", "x")):
                words = form_say(option, value, verb, example)
                assert words and "--" not in words and "{" not in words, (option, verb)


def test_a_message_only_error_is_said_as_it_is(tmp_path: Path) -> None:
    """An error raised without parts names no option: each front end says its message."""
    exc = InputError("the file holds 1 frame; gait needs a recording of at least two steps "
                     "of walking")
    assert not exc.structured and exc.words(form_say) is None
    assert no_walk(exc, tmp_path / "reference.trc", "trial 3.trc") == (
        f"'trial 3.trc' has no walk the report can use: {exc}. {WHAT_TO_DO}")


ROOT = Path(__file__).resolve().parents[2]


def _strings(path: Path) -> list[tuple[int, str]]:
    """The string constants of a module but its docstrings (and f-strings' pieces)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    docs = {id(n.value) for n in ast.walk(tree) if isinstance(n, ast.Expr)
            and isinstance(n.value, ast.Constant)}
    return [(n.lineno, n.value) for n in ast.walk(tree) if isinstance(n, ast.Constant)
            and isinstance(n.value, str) and id(n) not in docs]


def test_no_engine_message_names_a_flag_by_itself() -> None:
    """The analysis's errors name the options for files from other labs as tokens, never
    as flags written out: a page says a message without parts as it is (no phrase mapping
    any more), so a flag there would reach it."""
    flags = [f for flag in FLAGS.values() for f in flag.split("/")]
    found = []
    for path in [ROOT / "engine" / "mocap.py", ROOT / "engine" / "gait.py",
                 *sorted((ROOT / "engine" / "io").glob("*.py"))]:
        for line, text in _strings(path):
            if any(f in text for f in flags):
                found.append(f"{path.relative_to(ROOT)}:{line}: {text!r}")
    assert not found, found
