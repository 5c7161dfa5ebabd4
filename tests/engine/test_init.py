"""The engine package's re-exports (``from engine import GaitAnalysis``)."""

from __future__ import annotations

import importlib
import subprocess
import sys

import pytest

import engine


def test_every_reexport_is_the_object_of_its_module() -> None:
    assert set(engine.__all__) == {"__version__", *engine._EXPORTS}
    for name, module in engine._EXPORTS.items():
        assert getattr(engine, name) is getattr(importlib.import_module(module), name), name
    assert set(engine.__all__) <= set(dir(engine))


def test_unknown_name_is_an_attribute_error() -> None:
    with pytest.raises(AttributeError, match="no attribute 'GaitAnalyzer'"):
        engine.GaitAnalyzer  # noqa: B018
    with pytest.raises(ImportError):
        exec("from engine import GaitAnalyzer", {})


def test_import_engine_loads_no_module_until_a_name_is_used() -> None:
    code = ("import sys, engine; before = 'engine.gait' in sys.modules; "
            "from engine import GaitAnalysis; "
            "print(before, 'engine.gait' in sys.modules, GaitAnalysis.__module__)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, timeout=120).stdout.split()
    assert out == ["False", "True", "engine.gait"]


def test_file_loaders_and_gait_cycles_are_reexported() -> None:
    """The loaders of other tools' files and the gait cycles are what a research engineer
    reaches for: importable from ``engine`` like ``load_feet``."""
    from engine import (
        GaitCycle,
        gait_cycles,
        load_depth_image,
        load_imu,
        load_intrinsics,
        load_point_cloud,
    )
    from engine.gait import GaitCycle as Gc
    from engine.imu.io import load_imu as li
    from engine.pointcloud import load_point_cloud as lp

    assert GaitCycle is Gc and load_imu is li and load_point_cloud is lp
    assert all(callable(f) for f in (gait_cycles, load_depth_image, load_intrinsics))
