"""Counts and lists written in the right number in messages for people (engine errors,
server and CLI messages).

"1 sensor", "2 sensors", "sensor S3 has", "sensors S3, S5 have": never "sensor(s)", which
a clinician reading a message has to decode.
"""

from __future__ import annotations

from collections.abc import Sequence


def count(n: int, noun: str, nouns: str | None = None) -> str:
    """``n`` and the noun in the number ``n`` asks for.

    Args:
        n: how many.
        noun: the singular ("sensor").
        nouns: the plural when it is not ``noun + "s"`` ("passes").

    Returns:
        "1 sensor", "0 sensors", "2 sensors".
    """
    return f"{n} {noun if n == 1 else nouns or noun + 's'}"


def named(noun: str, names: Sequence[str], verb: str = "", verbs: str = "",
          nouns: str | None = None) -> str:
    """The noun, the names listed, and the verb, in the number the list asks for.

    Args:
        noun: the singular ("sensor").
        names: what is named (at least one).
        verb: the verb after one name ("has"), or "" for none.
        verbs: the verb after several names ("have").
        nouns: the plural when it is not ``noun + "s"``.

    Returns:
        "sensor S3 has", "sensors S3, S5 have" (or without a verb).
    """
    one = len(names) == 1
    words = [noun if one else nouns or noun + "s", ", ".join(names)]
    if verb or verbs:
        words.append(verb if one else verbs)
    return " ".join(words)
