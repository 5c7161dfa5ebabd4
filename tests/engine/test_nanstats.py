"""engine.nanstats: numpy's NaN reductions, silently NaN on all-NaN slices."""

from __future__ import annotations

import threading
import warnings

import numpy as np
import pytest

from engine import nanstats

FUNCS = ["nanmean", "nanmedian", "nanstd", "nanmax", "nanmin"]


@pytest.mark.parametrize("name", FUNCS)
@pytest.mark.parametrize("axis", [None, 0, 1, (0, 2)])
def test_matches_numpy_and_never_warns(name: str, axis: int | tuple[int, ...] | None) -> None:
    rng = np.random.default_rng(3)
    a = rng.normal(size=(6, 5, 3))
    a[rng.random(a.shape) < 0.3] = np.nan
    a[:, 2] = np.nan  # whole slices missing along axis 0
    a[4] = np.nan  # ... and along axes 1 and 2
    with warnings.catch_warnings(record=True):
        warnings.simplefilter("ignore")
        expected = getattr(np, name)(a, axis=axis)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any RuntimeWarning fails the test
        got = getattr(nanstats, name)(a, axis=axis)
    np.testing.assert_allclose(got, expected, equal_nan=True)


def test_all_nan_and_empty_inputs() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert np.isnan(nanstats.nanmean(np.full(4, np.nan)))
        assert np.isnan(nanstats.nanmedian([np.nan]))
        out = nanstats.nanmean(np.zeros((0, 3)), axis=0)
    assert out.shape == (3,) and np.isnan(out).all()


def test_leaves_the_warning_filters_alone_under_threads() -> None:
    """The point of the module: no process-wide filter swapping from worker threads."""
    before = list(warnings.filters)
    a = np.full((50, 25, 3), np.nan)

    def work() -> None:
        for _ in range(200):
            nanstats.nanmean(a, axis=0)

    threads = [threading.Thread(target=work) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert warnings.filters == before
