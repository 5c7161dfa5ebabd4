"""Typed exceptions raised by the engine.

Every error that a user can cause (bad file, too little data, unreachable sensor)
raises a subclass of :class:`GaitrigError` whose message says what to fix. The API
maps these to HTTP 4xx responses.

The message (``str(exc)``) is ``gaitrig gait``'s: its advice names command-line flags
("give it with --up, e.g. --up x"). An error whose fix is one of the analysis's options
for files from other labs (:data:`OPTIONS`) says it in parts instead, each option a
token (:attr:`GaitrigError.reason`, :attr:`GaitrigError.advice`,
:attr:`GaitrigError.example`): its message is the parts said by :func:`cli_say` (the
flags), and a front end with other controls (a web form) or none (a reference upload)
says the same parts its own way (:meth:`GaitrigError.words`).
"""

from __future__ import annotations

import re
from collections.abc import Callable

#: The options for files from other labs an error's advice can name, as
#: :func:`engine.mocap.feet_from_file`'s arguments: ``up`` (vertical axis), ``units``
#: (length unit), ``markers`` (the left and right foot markers, given together),
#: ``ankle_markers`` (how ankle markers are taken) and ``ankle_width_mm``.
OPTIONS = ("up", "units", "markers", "ankle_markers", "ankle_width_mm")
#: What an advice token asks of its option: ``""`` names it (with the value given or the
#: token's), ``"give"`` set it, ``"by"`` the same as a means ("… by giving …"),
#: ``"change"`` choose another value than the one given (or the automatic one),
#: ``"clear"`` leave it out (automatic), ``"both"`` give both of a pair or neither.
VERBS = ("", "give", "by", "change", "clear", "both")
#: A token in :attr:`GaitrigError.reason` or :attr:`GaitrigError.advice`:
#: ``{option}``, ``{option=value}``, ``{option:verb}`` or ``{option=value:verb}``. Other
#: braces are text.
TOKEN = re.compile(r"\{(" + "|".join(OPTIONS) + r")(?:=([A-Za-z0-9_+,.-]+))?"
                   r"(?::(" + "|".join(v for v in VERBS if v) + r"))?\}")

#: How a front end says a token: ``say(option, value, verb, example)`` with the token's
#: option, its ``=value`` (None without), its verb (``""`` without) and the error's
#: :attr:`GaitrigError.example`.
Say = Callable[[str, str | None, str, str | None], str]

#: ``gaitrig gait``'s flag of each option (:data:`OPTIONS`).
FLAGS = {"up": "--up", "units": "--units", "markers": "--left/--right",
         "ankle_markers": "--ankle-markers", "ankle_width_mm": "--ankle-width-mm"}


def cli_say(option: str, value: str | None, verb: str, example: str | None) -> str:
    """A token (:data:`Say`) as ``gaitrig gait``'s flags: the words of ``str(exc)``.

    Args:
        option: The token's option (:data:`OPTIONS`).
        value: Its ``=value``; None without one.
        verb: Its verb (:data:`VERBS`).
        example: The error's example value of the option; None without one.

    Returns:
        ``{up=z}`` "--up z", ``{up:give}`` with example ``x`` "give it with --up, e.g.
        --up x", ``{up:change}`` with example ``z`` "give --up z or leave it out",
        ``{units:change}`` "fix --units or leave it out", ``{markers:by}`` "with
        --left/--right", ``{ankle_markers=lateral:clear}`` "leave --ankle-markers lateral
        out", ``{markers:both}`` "give both --left and --right marker names, or neither".
    """
    flag = FLAGS[option]
    first = "--left" if option == "markers" else flag  # the left one of a pair
    named = flag if value is None else f"{first} {value}"
    eg = "" if example is None else f", e.g. {first} {example}"
    if verb == "give":
        if option == "units":
            return "give the units explicitly"
        return f"give it with {flag}{eg}"
    if verb == "by":
        return f"with {flag}{eg}"
    if verb == "change":
        return (f"fix {flag}" if example is None else f"give {first} {example}"
                ) + " or leave it out"
    if verb == "clear":
        return f"leave {named} out"
    if verb == "both":
        if option == "markers":
            return "give both --left and --right marker names, or neither"
        return f"give {flag} for both or neither"
    return named


class GaitrigError(Exception):
    """Base class of every user-facing engine error.

    ``str(exc)`` is ``gaitrig gait``'s words. An error whose fix is an option for files
    from other labs, or which names one, is raised with keyword-only parts without flags
    instead of a message, and its message is the parts said by :func:`cli_say`; a message
    given with parts is said instead (the command line's own words, e.g. a pointer to its
    documentation that a page has not).

    Args:
        *args: As for :class:`Exception`: the message first; none for an error given in
            parts (:meth:`words` with :func:`cli_say` is then its message).
        reason: What is wrong, without advice: for any front end, including one with no
            options (a reference upload). An option the person gave is a token
            (:data:`TOKEN`) naming it with its value, e.g. ``"{up=z} contradicts the
            markers: …"``.
        advice: What to do, with each option named as a token, e.g. ``"{up:give}"``,
            ``"choose one subject's feet {markers:by}"``, ``"{ankle_markers:clear}, or
            {markers:clear} to have the ankle joint centres estimated"``; None when the
            reason is all there is to say without the command line.
        option: The option (:data:`OPTIONS`) that fixes it, when the advice names none
            as a token (default: the first it names).
        example: A value of the advice's option that would do (``"x"`` for ``up``,
            ``"LHEE"`` for ``markers``, the left one), said by its tokens.
        sep: What joins the reason and the advice in :meth:`words` (``"; "``, ``": "`` or
            ``". "``; so in the message made from them).

    Attributes:
        reason: As given; None for an error raised with its message only (which names
            no option: a front end says it as it is).
        advice: As given.
        example: As given.
        sep: As given.
    """

    reason: str | None = None
    advice: str | None = None
    example: str | None = None
    sep: str = "; "

    _option: str | None = None

    def __init__(self, *args: object, reason: str | None = None, advice: str | None = None,
                 option: str | None = None, example: str | None = None,
                 sep: str = "; ") -> None:
        self._option = option
        self.reason = reason
        self.advice = advice
        self.example = example
        self.sep = sep
        if not args and self.structured:
            args = (self.words(cli_say),)
        super().__init__(*args)

    @property
    def structured(self) -> bool:
        """Whether the error gives its reason or advice in parts (else only ``str()``)."""
        return self.reason is not None or self.advice is not None

    @property
    def option(self) -> str | None:
        """The option that fixes it: as given, else the first the advice names (None
        without one)."""
        m = TOKEN.search(self.advice or "")
        return self._option or (m[1] if m else None)

    def words(self, say: Say, advice: bool = True) -> str | None:
        """The reason and (with ``advice``) the advice, joined by :attr:`sep`, their
        tokens said by ``say``.

        Args:
            say: How the front end says a token (:data:`Say`).
            advice: Include the advice (False: the reason alone, for a front end whose
                controls cannot follow it).

        Returns:
            The words; None when there are none (an error given with its message only,
            or without ``advice`` one that gives advice alone).
        """
        parts = [p for p in (self.reason, self.advice if advice else None) if p is not None]
        if not parts:
            return None
        return self.sep.join(fill(p, say, self.example) for p in parts)


def fill(template: str, say: Say, example: str | None = None) -> str:
    """Say the option tokens of a reason or an advice.

    Args:
        template: Text with tokens (:data:`TOKEN`).
        say: How the front end says a token (:data:`Say`).
        example: The error's example value, passed on to ``say``.

    Returns:
        ``template`` with each token replaced by ``say(option, value, verb, example)``.
    """
    return TOKEN.sub(lambda m: say(m[1], m[2], m[3] or "", example), template)


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
