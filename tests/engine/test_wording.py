"""Counts and named lists in messages for people are in the right number, never "(s)"."""

from __future__ import annotations

from engine.wording import count, named


def test_count_says_one_noun_or_several() -> None:
    assert count(1, "sensor") == "1 sensor"
    assert count(0, "sensor") == "0 sensors"
    assert count(2, "deleted reference") == "2 deleted references"
    assert count(3, "pass", "passes") == "3 passes"
    assert count(1, "pass", "passes") == "1 pass"


def test_named_agrees_noun_and_verb_with_the_list() -> None:
    assert named("sensor", ["S3"], "has", "have") == "sensor S3 has"
    assert named("sensor", ["S3", "S5"], "has", "have") == "sensors S3, S5 have"
    assert named("node", ["S1"], "is", "are") == "node S1 is"
    assert named("sensor", ["S1", "S2"]) == "sensors S1, S2"
    assert named("sensor", ("S2",)) == "sensor S2"
