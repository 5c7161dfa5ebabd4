"""``gaitrig backup`` / ``--verify`` / ``restore`` against a plain copy of the same data.

Builds a data folder in a temporary directory (a SQLite database with a few thousand
rows, and recording parts of random bytes: ``--mib`` in total, as 8 parts of 3 files),
then times, in the same run: the peer, a plain copy (the SQLite online backup of the
database plus ``shutil.copyfile`` + ``fsync`` of every file into a folder), and the
backup into one archive, its verification and its restore. ``ratio_vs_copy`` is
backup / copy time (the backup also hashes every byte and writes a tar). The Python
memory the backup allocates at its peak (``tracemalloc``, a second backup) shows that
files are streamed: it does not grow with the data. Prints one JSON line.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sqlite3
import sys
import tempfile
import time
import tracemalloc
from collections.abc import Sequence
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.server import backup as bk  # noqa: E402


def _data_folder(root: Path, mib: int) -> int:
    """A data folder with a database and ``mib`` MiB of parts; returns the file count."""
    from app.db import data as m
    from app.db.base import make_engine, make_session_factory

    engine = make_engine(root / "gaitrig.sqlite3")
    with make_session_factory(engine)() as db:
        p = m.Project(name="bench")
        db.add(p)
        db.flush()
        for k in range(2000):
            s = m.Subject(project_id=p.id, code=f"B{k:05d}", notes="x" * 200)
            db.add(s)
        db.commit()
    engine.dispose()
    per_file = mib * 2**20 // 24
    block = os.urandom(2**20)
    n = 0
    for r in range(8):
        d = root / "recordings" / f"R20260101-0000{r:02d}-bnch" / "S1"
        d.mkdir(parents=True)
        for name in ("frames.bin", "index.json", "meta.json"):
            with open(d / name, "wb") as fh:
                left = per_file
                while left > 0:
                    fh.write(block[: min(left, len(block))])
                    left -= len(block)
            n += 1
        (d / "manifest.json").write_text("{}")
        n += 1
    return n


def _copy(src: Path, dst: Path) -> None:
    dst.mkdir()
    s = sqlite3.connect(src / "gaitrig.sqlite3")
    d = sqlite3.connect(dst / "gaitrig.sqlite3")
    s.backup(d)
    d.close()
    s.close()
    for p in sorted(src.rglob("*")):
        if p.is_file() and not p.name.startswith("gaitrig.sqlite3"):
            t = dst / p.relative_to(src)
            t.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(p, t)
            with open(t, "rb") as fh:
                os.fsync(fh.fileno())


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mib", type=int, default=256, help="MiB of recording parts")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="gaitrig-bench-backup-") as t:
        tmp = Path(t)
        var = tmp / "var"
        var.mkdir()
        n_files = _data_folder(var, args.mib)
        t0 = time.perf_counter()
        _copy(var, tmp / "copy")
        copy_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        res = bk.create_backup(var, tmp / "b.tar")
        backup_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        ok = bk.verify_backup(res.path).ok
        verify_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        bk.restore_backup(res.path, tmp / "restored", [], without_deletion_log=True)
        restore_s = time.perf_counter() - t0
        tracemalloc.start()
        bk.create_backup(var, tmp / "b2.tar")
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    print(json.dumps({
        "bench": "backup", "mib": args.mib, "files": n_files, "verified": ok,
        "copy_s": round(copy_s, 3), "backup_s": round(backup_s, 3),
        "ratio_vs_copy": round(backup_s / copy_s, 3), "verify_s": round(verify_s, 3),
        "restore_s": round(restore_s, 3),
        "backup_mib_per_s": round(args.mib / backup_s, 1),
        "peak_python_mib_during_backup": round(peak / 2**20, 2),
    }))
    return 0


if __name__ == "__main__":
    sys.exit(main())
