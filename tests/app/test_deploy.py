"""docker-compose.yml and the Dockerfile stay consistent with the CLI and the default rig."""

from __future__ import annotations

import json
import re
from pathlib import Path

from app.cli import build_parser
from engine.sim.rig import default_avenue_rig

ROOT = Path(__file__).resolve().parents[2]


def _commands() -> dict[str, list[str]]:
    text = (ROOT / "docker-compose.yml").read_text()
    out: dict[str, list[str]] = {}
    service = None
    for line in text.splitlines():
        m = re.match(r"^  ([a-z0-9-]+):\s*$", line)
        if m:
            service = m.group(1)
        m = re.match(r"^\s+command:\s*(\[.*\])\s*$", line)
        if m and service:
            out[service] = json.loads(m.group(1))
    return out


def test_compose_commands_parse_with_the_cli() -> None:
    cmds = _commands()
    parser = build_parser()
    server = parser.parse_args(cmds["server"][1:])
    assert server.command == "serve" and server.host == "0.0.0.0"
    node_ids = []
    for name, cmd in cmds.items():
        assert cmd[0] == "gaitrig"
        if name.startswith("node-"):
            args = parser.parse_args(cmd[1:])
            assert args.command == "node" and args.backend == "sim"
            assert args.server == f"ws://server:{server.port}"
            node_ids.append(args.id)
    assert sorted(node_ids) == sorted(default_avenue_rig(0).sensor_ids)


def test_dockerfile_default_command_parses() -> None:
    text = (ROOT / "Dockerfile").read_text()
    cmd = json.loads(re.search(r"^CMD (\[.*\])$", text, re.M).group(1))  # type: ignore[union-attr]
    assert build_parser().parse_args(cmd[1:]).command == "serve"
    assert "COPY static" in text  # the console is served from the image
