"""``gaitrig gait``'s words of an engine error raised in parts: its tokens said as the
command line's flags (:func:`engine.errors.cli_say`), the message made from them."""

from __future__ import annotations

import pickle

import pytest

from engine.errors import FLAGS, OPTIONS, VERBS, GaitrigError, InputError, cli_say, fill


@pytest.mark.parametrize(("token", "example", "said"), [
    ("{up}", None, "--up"),
    ("{up=-z}", None, "--up -z"),
    ("{up:give}", None, "give it with --up"),
    ("{up:give}", "x", "give it with --up, e.g. --up x"),
    ("{up:change}", "z", "give --up z or leave it out"),
    ("{units=m}", None, "--units m"),
    ("{units:give}", None, "give the units explicitly"),
    ("{units:change}", None, "fix --units or leave it out"),
    ("{markers}", None, "--left/--right"),
    ("{markers:by}", None, "with --left/--right"),
    ("{markers:by}", "A:LANK", "with --left/--right, e.g. --left A:LANK"),
    ("{markers:both}", None, "give both --left and --right marker names, or neither"),
    ("{markers:clear}", None, "leave --left/--right out"),
    ("{ankle_markers=lateral}", None, "--ankle-markers lateral"),
    ("{ankle_markers:clear}", None, "leave --ankle-markers out"),
    ("{ankle_markers=lateral:clear}", None, "leave --ankle-markers lateral out"),
    ("{ankle_width_mm}", None, "--ankle-width-mm"),
    ("{ankle_width_mm=68,72}", None, "--ankle-width-mm 68,72"),
    ("{ankle_width_mm:clear}", None, "leave --ankle-width-mm out"),
])
def test_cli_say_names_the_flags(token: str, example: str | None, said: str) -> None:
    assert fill(token, cli_say, example) == said


def test_every_token_is_said_with_its_flag() -> None:
    for option in OPTIONS:
        for verb in VERBS:
            for value, example in ((None, None), ("x", "x")):
                words = cli_say(option, value, verb, example)
                assert "{" not in words, (option, verb)
                if not (option == "units" and verb == "give"):
                    assert FLAGS[option].split("/")[0] in words, (option, verb, words)


def test_the_message_of_an_error_in_parts_is_its_parts_as_flags() -> None:
    exc = InputError(reason="cannot tell the vertical axis", advice="{up:give}", example="x")
    assert str(exc) == "cannot tell the vertical axis; give it with --up, e.g. --up x"
    assert exc.args == (str(exc),) and exc.option == "up"
    exc = InputError(reason="{ankle_width_mm} places centres", advice="leave it out",
                     option="ankle_width_mm", sep=": ")
    assert str(exc) == "--ankle-width-mm places centres: leave it out"
    assert str(InputError(advice="{markers:both}")) == (
        "give both --left and --right marker names, or neither")


def test_a_message_is_said_as_given() -> None:
    """An error raised with its message only, or with its own message beside parts."""
    assert str(GaitrigError("no steps were found")) == "no steps were found"
    exc = InputError("see docs/gait-json.md; name them with --left/--right",
                     reason="see the names", advice="name them {markers:by}")
    assert str(exc) == "see docs/gait-json.md; name them with --left/--right"
    assert str(GaitrigError()) == ""


def test_an_error_in_parts_survives_pickling() -> None:
    """(as from a worker process): the same message and parts."""
    exc = InputError(reason="{up=z} contradicts the markers", advice="{up:change}",
                     example="-y")
    back = pickle.loads(pickle.dumps(exc))
    assert type(back) is InputError and str(back) == str(exc)
    assert (back.reason, back.advice, back.example) == (exc.reason, exc.advice, exc.example)
