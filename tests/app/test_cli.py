"""``app.cli``: a refused ``GAITRIG_*`` setting is a message naming it, not a traceback."""

from __future__ import annotations

from pathlib import Path

import pytest

from app.cli import main, settings_error


def test_a_refused_setting_is_named_without_its_value(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv("GAITRIG_NODE_TOKEN", "sh0rt")
    monkeypatch.setenv("GAITRIG_PORT", "eighty")
    rc = main(["serve", "--no-viewer", "--data-dir", str(tmp_path / "var")])
    out, err = capsys.readouterr()
    assert rc == 2 and out == ""
    lines = err.splitlines()
    assert len(lines) == 2 and all(line.startswith("gaitrig serve: setting GAITRIG_")
                                   for line in lines), err
    assert "GAITRIG_NODE_TOKEN" in err and "at least 8 characters" in err
    assert "GAITRIG_PORT" in err and "integer" in err
    assert "sh0rt" not in err and "Traceback" not in err
    assert not (tmp_path / "var").exists()  # refused before anything was created


def test_the_option_that_sets_it_is_refused_the_same_way(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["serve", "--token", "sh0rt", "--data-dir", str(tmp_path / "var")]) == 2
    assert "GAITRIG_NODE_TOKEN" in capsys.readouterr().err


def test_other_errors_are_not_taken_for_settings() -> None:
    from pydantic import BaseModel, ValidationError

    class Other(BaseModel):
        n: int

    with pytest.raises(ValidationError) as e:
        Other(n="x")  # type: ignore[arg-type]
    assert settings_error(e.value) is None
    assert settings_error(ValueError("x")) is None
