"""The ``gaitrig`` command line.

Each sub-command lives in its own module ``app.commands.<name>`` exposing
``HELP: str``, ``add_arguments(parser)`` and ``run(args) -> int``; this file only
dispatches, so commands are added without touching each other.
"""

from __future__ import annotations

import argparse
import gc
import importlib
import os
import pkgutil
import sys
from collections.abc import Sequence

import app.commands


def _command_modules() -> dict[str, object]:
    mods: dict[str, object] = {}
    for info in sorted(pkgutil.iter_modules(app.commands.__path__), key=lambda i: i.name):
        if info.name.startswith("_"):
            continue
        mods[info.name.replace("_", "-")] = importlib.import_module(f"app.commands.{info.name}")
    return mods


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="gaitrig",
        description="Multi-depth-camera motion capture and gait lab.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, mod in _command_modules().items():
        help_text = getattr(mod, "HELP", "")
        p = sub.add_parser(name, help=help_text, description=help_text)
        mod.add_arguments(p)  # type: ignore[attr-defined]
        p.set_defaults(_run=mod.run)  # type: ignore[attr-defined]
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command ``argv`` names (default: this process's command line).

    Returns:
        The exit status.
    """
    code = _run(argv)
    if argv is None:
        # The process's own command line: it ends when this returns. Python's finalisation
        # would then run full cyclic collections over every object still alive (the
        # libraries' modules: scipy, open3d, numba... once a command used them), ≈ 0.5–2 s
        # of CPU at every server or node stop and after every command; frozen objects are
        # skipped. Nothing needs them collected: files and sockets are closed by the
        # commands, and atexit handlers and module teardown still run. (Not for ``argv``
        # given: a test calling this in its own process goes on running.)
        gc.freeze()
    return code


def _run(argv: Sequence[str] | None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    try:
        code = int(args._run(args) or 0)
        sys.stdout.flush()
        return code
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        # the reader went away (`gaitrig gait FILE --json | head`): no traceback; stdout
        # goes to devnull so that the interpreter's final flush cannot raise again
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1
    except Exception as exc:
        message = settings_error(exc)
        if message is None:
            raise
        for line in message.splitlines():
            print(f"gaitrig {args.command}: {line}", file=sys.stderr)
        return 2


def settings_error(exc: BaseException) -> str | None:
    """What is wrong with the ``GAITRIG_*`` settings, when ``exc`` says so; else None.

    A setting the server or a node refuses (``GAITRIG_NODE_TOKEN`` too short, a port that
    is not a number ...) is named with its environment variable, without its value (it
    may be a password), instead of a pydantic traceback.

    Args:
        exc: The exception a command raised.

    Returns:
        One line per refused setting, or None when ``exc`` is not about the settings.
    """
    from pydantic import ValidationError

    if not isinstance(exc, ValidationError) or exc.title != "Settings":
        return None
    lines = []
    for err in exc.errors():
        field = str(err["loc"][0]) if err["loc"] else ""
        lines.append(f"setting GAITRIG_{field.upper()} (or the option that sets it) "
                     f"refused: {err['msg']}")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
