"""Long IMU CSV import: time and peak memory of ``engine.imu.io.load_imu`` vs ``numpy``.

A synthetic recording (default 30 min at 200 Hz, 9D, 360 000 rows, ~37 MB of text) is
written as a generic CSV and read by ``load_imu`` (header and unit detection, NaN and
text cells, checks) and by the peer ``numpy.loadtxt`` (numbers only, nothing checked) in
the same run. Peak memory is traced separately (``tracemalloc``), so the times are not
slowed by it.

Usage: ``python bench/imu_import.py [MINUTES] [RATE_HZ]``. Prints ONE JSON line.
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != ROOT / "bench"]
sys.path.insert(0, str(ROOT))

from engine.imu.io import load_imu  # noqa: E402


def _write(path: Path, minutes: float, rate: float) -> int:
    n = int(minutes * 60 * rate)
    rng = np.random.default_rng(0)
    t = np.arange(n) / rate
    gyr = np.degrees(rng.normal(0, 1.0, (n, 3)))  # deg/s, fast enough to be detected
    acc = np.array([0.0, 0.0, 1.0]) + rng.normal(0, 0.05, (n, 3))  # g
    mag = np.array([20.0, 0.0, -40.0]) + rng.normal(0, 0.5, (n, 3))  # µT
    data = np.column_stack([t, gyr, acc, mag])
    header = "time,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z,mag_x,mag_y,mag_z"
    np.savetxt(path, data, delimiter=",", header=header, comments="", fmt="%.6f")
    return n


def main() -> None:
    minutes = float(sys.argv[1]) if len(sys.argv) > 1 else 30.0
    rate = float(sys.argv[2]) if len(sys.argv) > 2 else 200.0
    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / "long.csv"
        n = _write(p, minutes, rate)
        size = p.stat().st_size
        t0 = time.perf_counter()
        rec = load_imu(p)
        t_ours = time.perf_counter() - t0
        assert len(rec) == n
        t0 = time.perf_counter()
        ref = np.loadtxt(p, delimiter=",", skiprows=1)
        t_peer = time.perf_counter() - t0
        assert ref.shape == (n, 10)
        del rec, ref
        tracemalloc.start()
        load_imu(p)
        peak_ours = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        tracemalloc.start()
        np.loadtxt(p, delimiter=",", skiprows=1)
        peak_peer = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    numbers = n * 10 * 8
    print(json.dumps({
        "rows": n, "file_mb": round(size / 2**20, 1), "numbers_mb": round(numbers / 2**20, 1),
        "load_imu_s": round(t_ours, 2), "loadtxt_s": round(t_peer, 2),
        "time_ratio_vs_loadtxt": round(t_ours / t_peer, 2),
        "load_imu_peak_mb": round(peak_ours / 2**20, 1),
        "loadtxt_peak_mb": round(peak_peer / 2**20, 1),
        "peak_ratio_vs_loadtxt": round(peak_ours / peak_peer, 2),
        "peak_per_numbers": round(peak_ours / numbers, 2),
    }))


if __name__ == "__main__":
    main()
