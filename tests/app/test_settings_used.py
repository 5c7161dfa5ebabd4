"""Every setting does something: a field of :class:`app.config.Settings` that no code reads
(``GAITRIG_PUBLIC_HOST`` was set in docker-compose.yml and read by nothing) promises an
effect it does not have."""

from __future__ import annotations

import re
from pathlib import Path

from app.config import Settings

ROOT = Path(__file__).resolve().parents[2]


def test_every_setting_is_read_by_the_application() -> None:
    code = "\n".join(p.read_text() for p in sorted((ROOT / "app").rglob("*.py"))
                     if p != ROOT / "app" / "config.py")
    # read as an attribute, or by name (getattr)
    unread = [f for f in Settings.model_fields
              if not re.search(rf"\.{f}\b|[\"']{f}[\"']", code)]
    assert not unread, f"settings no code reads (remove them or use them): {unread}"


def test_compose_sets_only_settings_that_exist() -> None:
    compose = (ROOT / "docker-compose.yml").read_text()
    named = set(re.findall(r"\bGAITRIG_([A-Z0-9_]+)\b", compose))
    assert named, "docker-compose.yml names no GAITRIG_ setting"
    unknown = sorted(v for v in named if v.lower() not in Settings.model_fields)
    assert not unknown, f"docker-compose.yml sets what Settings does not have: {unknown}"
