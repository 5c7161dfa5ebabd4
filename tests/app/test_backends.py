"""Backend selection and the import guard of the hardware backend."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from app.cli import main
from engine.errors import InputError


@pytest.mark.skipif(importlib.util.find_spec("pyk4a") is not None, reason="pyk4a is installed")
def test_k4a_without_pyk4a_says_what_to_install(capsys: pytest.CaptureFixture[str]) -> None:
    from app.nodes.backends.k4a import K4ABackend

    with pytest.raises(InputError, match=r"pip install -e '\.\[k4a\]'"):
        K4ABackend()
    assert main(["node", "--id", "S1", "--backend", "k4a"]) == 2
    assert "pyk4a" in capsys.readouterr().err


def test_bad_node_arguments_are_clear(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["node", "--id", "S9", "--backend", "sim"]) == 2
    assert "no sensor 'S9' in the rig" in capsys.readouterr().err
    assert main(["node", "--id", "S1", "--backend", "replay", "--recording",
                 str(tmp_path)]) == 2
    assert "not a recording part" in capsys.readouterr().err
    assert main(["node", "--id", "S1", "--clock-offset", "99"]) == 2
    assert "within ±10 s" in capsys.readouterr().err
