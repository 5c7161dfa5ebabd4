"""Shared fixtures of the calibration API tests."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.integration.conftest import Rig


@pytest.fixture
def rig(tmp_path: Path) -> Iterator[Rig]:
    """A server with real node processes over loopback (see
    :class:`tests.integration.conftest.Rig`), closed after the test."""
    r = Rig(tmp_path)
    try:
        yield r
    finally:
        r.close()
