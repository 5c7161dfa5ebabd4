"""The documentation against the code: fails when README, CONTRIBUTING or docs/ drift.

* every ```` ```python ```` block runs as written in an empty folder (a block after
  ``<!-- docs-test: skip (why) -->`` needs a server or a recording and is only compiled);
* every ``make <target>`` in code is a Makefile target; every ``gaitrig <command>`` is a
  sub-command of the CLI, and every ``--option`` written after it is one of its options;
* every ``--option`` given to a ``bench/<name>.py`` is one that bench parses;
* every ``GAITRIG_*`` variable and every ``Settings.<field>`` / setting ``<field>`` named
  is a field of :class:`app.config.Settings`;
* every file path named exists, every ``app.x.y`` / ``engine.x.y`` object resolves, every
  identifier in code (``snake_case``, ``camelCase``) occurs in the sources, and what a
  skipped block imports exists;
* every ``/api/...`` endpoint named is served by the app;
* the gait JSON example of ``docs/gait-json.md`` has exactly the keys ``to_dict()`` gives,
  and the node health fields of ``docs/backbone.md`` are those of ``GET /api/nodes``.
"""

from __future__ import annotations

import argparse
import ast
import importlib
import json
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", ROOT / "CONTRIBUTING.md", *sorted((ROOT / "docs").glob("*.md"))]
SKIP_MARK = "<!-- docs-test: skip"

_FENCE = re.compile(r"^```([^\n`]*)\n(.*?)^```[ \t]*$", re.M | re.S)
_SPAN = re.compile(r"`([^`\n]+)`")


def _rel(path: Path) -> str:
    return str(path.relative_to(ROOT))


def _blocks(path: Path) -> Iterator[tuple[str, str, int, bool]]:
    """``(language, code, line, skipped)`` of every fenced block of a Markdown file."""
    text = path.read_text()
    for m in _FENCE.finditer(text):
        before = text[: m.start()].rstrip().rsplit("\n", 1)[-1]
        yield (m.group(1).strip().split(" ")[0], m.group(2), text.count("\n", 0, m.start()) + 1,
               before.startswith(SKIP_MARK))


def _code_lines() -> Iterator[tuple[str, str]]:
    """``(where, code)`` for every inline code span and every line of a non-JSON block."""
    for path in DOCS:
        text = path.read_text()
        prose = _FENCE.sub("", text)
        for m in _SPAN.finditer(prose):
            yield _rel(path), m.group(1)
        for lang, code, line, _ in _blocks(path):
            if lang in ("json", "python"):
                continue
            for k, ln in enumerate(code.splitlines()):
                yield f"{_rel(path)}:{line + 1 + k}", ln


def _python_blocks() -> list[Any]:
    out = []
    for path in DOCS:
        for lang, code, line, skipped in _blocks(path):
            if lang == "python":
                out.append(pytest.param(code, skipped, id=f"{_rel(path)}:{line}"))
    return out


# ------------------------------------------------------------------ python snippets


@pytest.mark.parametrize(("code", "skipped"), _python_blocks())
def test_python_snippet_runs(code: str, skipped: bool, tmp_path: Path,
                             monkeypatch: pytest.MonkeyPatch) -> None:
    compiled = compile(code, "<docs snippet>", "exec")
    if skipped:
        # Needs a server or a recording: what it imports must still exist.
        for node in ast.walk(ast.parse(code)):
            if isinstance(node, ast.ImportFrom) and node.module:
                module = importlib.import_module(node.module)
                for alias in node.names:
                    assert hasattr(module, alias.name), f"{node.module}.{alias.name}"
            elif isinstance(node, ast.Import):
                for alias in node.names:
                    importlib.import_module(alias.name)
        return
    monkeypatch.chdir(tmp_path)
    exec(compiled, {"__name__": "__docs__"})


def test_docs_have_python_snippets() -> None:
    # The research page's examples are the point of this module: losing the fences (or
    # renaming the language) would silently turn every check above into nothing.
    ran = [p for p in _python_blocks() if not p.values[1]]
    assert len(ran) >= 4, [p.id for p in _python_blocks()]


# ------------------------------------------------------------------ command line


def _subparsers() -> dict[str, argparse.ArgumentParser]:
    from app.cli import build_parser

    parser = build_parser()
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    raise AssertionError("gaitrig has no sub-commands")


_GAITRIG = re.compile(r"(?:^|[\s$(/'\"])gaitrig ([a-z][a-z0-9_-]*)(.*)")
_OPTION = re.compile(r"(?<![\w-])(--[a-z][a-z0-9-]*)")


def test_cli_commands_and_options_named_in_docs_exist() -> None:
    subs = _subparsers()
    seen: set[str] = set()
    problems = []
    for where, code in _code_lines():
        for m in _GAITRIG.finditer(code):
            name, rest = m.group(1), m.group(2)
            seen.add(name)
            if name not in subs:
                problems.append(f"{where}: 'gaitrig {name}' is not a sub-command "
                                f"({', '.join(sorted(subs))})")
                continue
            known = {o for a in subs[name]._actions for o in a.option_strings}
            for opt in _OPTION.findall(rest.split("gaitrig ")[0]):
                if opt not in known:
                    problems.append(f"{where}: 'gaitrig {name}' has no option {opt}")
    assert not problems, "\n".join(problems)
    # The README's command table names every sub-command (a new one must be listed).
    assert set(subs) <= seen, f"sub-commands not in the docs: {sorted(set(subs) - seen)}"


def test_make_targets_named_in_docs_exist() -> None:
    targets = set(re.findall(r"^([a-z][\w-]*):", (ROOT / "Makefile").read_text(), re.M))
    named = {m for _, code in _code_lines() for m in re.findall(r"\bmake ([a-z][\w-]*)", code)}
    assert named, "the docs name no make target (README: make demo, make test)"
    assert named <= targets, f"not in the Makefile: {sorted(named - targets)}"


_BENCH = re.compile(r"bench/([a-z_]+)\.py(.*)")


def test_bench_options_named_in_docs_exist() -> None:
    problems = []
    for where, code in _code_lines():
        for m in _BENCH.finditer(code):
            src = ROOT / "bench" / f"{m.group(1)}.py"
            if not src.exists():
                problems.append(f"{where}: no bench/{m.group(1)}.py")
                continue
            text = src.read_text()
            for opt in _OPTION.findall(m.group(2).split("bench/")[0]):
                if f'"{opt}"' not in text:
                    problems.append(f"{where}: bench/{m.group(1)}.py has no option {opt}")
    assert not problems, "\n".join(problems)


# ------------------------------------------------------------------ settings


def test_settings_named_in_docs_exist() -> None:
    from app.config import Settings

    fields = set(Settings.model_fields)
    problems = []
    for path in DOCS:
        text = path.read_text()
        for var in set(re.findall(r"\bGAITRIG_([A-Z0-9_]+)\b", text)):
            if var.lower() not in fields:
                problems.append(f"{_rel(path)}: GAITRIG_{var} is not a Settings field")
        named = re.findall(r"\bSettings\.([a-z_]+)", text) + re.findall(
            r"\bsetting `([a-z_]+)`", text)
        for field in set(named):
            if field not in fields:
                problems.append(f"{_rel(path)}: setting {field!r} is not a Settings field")
    assert not problems, "\n".join(problems)


# ------------------------------------------------------------------ files and objects


_PATH = re.compile(r"(?<![\w/.-])((?:app|engine|bench|tests|docs|static|scripts|alembic)"
                   r"/[\w./-]*[\w])")


def test_file_paths_named_in_docs_exist() -> None:
    problems = []
    for path in DOCS:
        for m in _PATH.finditer(path.read_text()):
            p = m.group(1)
            nxt = path.read_text()[m.end():m.end() + 1]
            if nxt in "<*{":  # a pattern such as app/commands/<name>.py
                continue
            if not (ROOT / p).exists():
                problems.append(f"{_rel(path)}: {p} does not exist")
    assert not problems, "\n".join(problems)


_DOTTED = re.compile(r"(?<![\w/.])((?:app|engine)(?:\.[A-Za-z_]\w*)+)")


def _resolve(dotted: str) -> bool:
    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj: Any = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for attr in parts[i:]:
            if not hasattr(obj, attr):
                return False
            obj = getattr(obj, attr)
        return True
    return False


def test_python_objects_named_in_docs_exist() -> None:
    problems = []
    for where, code in _code_lines():
        for m in _DOTTED.finditer(code):
            if not _resolve(m.group(1)):
                problems.append(f"{where}: {m.group(1)} does not resolve")
    assert not problems, "\n".join(problems)


_SOURCES = ("app", "engine", "bench", "tests", "static", "scripts", "alembic")
#: Names in code spans that are conventions, not identifiers of the code.
_NOT_IDENTIFIERS = {"result_"}


def test_identifiers_named_in_docs_exist() -> None:
    # Names with an underscore or camelCase in code (functions, fields, JSON keys,
    # constants, test names) must occur in the sources: a rename shows up here.
    words: set[str] = set()
    for d in _SOURCES:
        for p in (ROOT / d).rglob("*"):
            if p.suffix in (".py", ".js", ".html", ".sh") and p.is_file():
                words |= set(re.findall(r"[A-Za-z_][A-Za-z0-9_]*", p.read_text()))
                words.add(p.stem)
    # the Makefile's variables (TEST_WORKERS, PYTEST_ARGS) are named in the docs too
    words |= set(re.findall(r"[A-Za-z_][A-Za-z0-9_]*", (ROOT / "Makefile").read_text()))
    problems = []
    for where, code in _code_lines():
        for ident in re.findall(r"\b[A-Za-z_][A-Za-z0-9_]{3,}\b", code):
            if ident.startswith("GAITRIG_") or ident in _NOT_IDENTIFIERS:
                continue  # settings: test_settings_named_in_docs_exist
            if ("_" in ident or re.search(r"[a-z][A-Z]", ident)) and ident not in words:
                problems.append(f"{where}: {ident} occurs nowhere in "
                                f"{', '.join(_SOURCES)} or the Makefile")
    assert not problems, "\n".join(sorted(set(problems)))


# ------------------------------------------------------------------ REST


@pytest.fixture(scope="module")
def api_app(tmp_path_factory: pytest.TempPathFactory) -> Any:
    from app.config import Settings
    from app.main import create_app

    return create_app(Settings(data_dir=tmp_path_factory.mktemp("docs-data"),
                               viewer_enabled=False))


def _served(app: Any, path: str) -> bool:
    from starlette.routing import Match, Mount

    for kind in ("http", "websocket"):
        scope = {"type": kind, "path": path, "method": "GET", "root_path": ""}
        for route in app.routes:
            if isinstance(route, Mount):  # the static console matches everything
                continue
            if route.matches(scope)[0] != Match.NONE:
                return True
    return False


def test_endpoints_named_in_docs_exist(api_app: Any) -> None:
    problems = []
    for path in DOCS:
        for m in re.finditer(r"(?<![\w/])(/api/(?:[\w\-/.]|\{[^}\n]*\}|<[^>\n]*>)+)",
                             path.read_text()):
            raw = m.group(1).rstrip("/.")
            concrete = re.sub(r"\{[^}]*\}|<[^>]*>", "x1", raw)
            if not _served(api_app, concrete):
                problems.append(f"{_rel(path)}: {raw} is not served")
    assert not problems, "\n".join(problems)


# ------------------------------------------------------------------ JSON fields


def _keys(doc: Any, prefix: str = "") -> set[str]:
    """Dotted key paths of a JSON document (list items merged; ``"..."`` placeholders
    stand for keys documented elsewhere and are left out)."""
    out: set[str] = set()
    if isinstance(doc, dict):
        if "..." in doc:
            return {prefix.rstrip(".")} if prefix else out
        for k, v in doc.items():
            out.add(prefix + k)
            out |= _keys(v, prefix + k + ".")
    elif isinstance(doc, list):
        for v in doc:
            out |= _keys(v, prefix)
    return out


def test_gait_json_example_matches_to_dict() -> None:
    from engine.gait import GaitAnalysis
    from engine.sim.straight_walk import synth_walk, walk_markers

    _, code, _, _ = next(b for b in _blocks(ROOT / "docs" / "gait-json.md")
                         if b[0] == "json")
    documented = _keys(json.loads(code))
    real = _keys(GaitAnalysis("heelstrike").fit(walk_markers(synth_walk())).to_dict())
    # A "..." placeholder stands for the six keys documented in the row above it.
    placeholders = {k for k in documented if k.startswith("summary.") and k.count(".") == 1
                    and not any(d.startswith(k + ".") for d in documented)}
    real_cmp = {k for k in real if not any(k.startswith(p + ".") for p in placeholders)}
    assert documented == real_cmp, (f"documented only: {sorted(documented - real_cmp)}; "
                                    f"to_dict only: {sorted(real_cmp - documented)}")


def test_node_health_fields_in_backbone_exist() -> None:
    from app.api.routes.nodes import NodeHealth

    text = (ROOT / "docs" / "backbone.md").read_text()
    m = re.search(r"`GET /api/nodes` → health per node: (.*?)\.\.\.", text, re.S)
    assert m, "docs/backbone.md no longer lists the node health fields"
    named = set(_SPAN.findall(m.group(1)))
    assert named and named <= set(NodeHealth.model_fields), named - set(NodeHealth.model_fields)
