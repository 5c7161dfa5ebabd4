"""Part folders for the transfer tests: random files and their SHA-256."""

from __future__ import annotations

import hashlib
import random
from pathlib import Path


def make_part(root: Path, sizes: dict[str, int], seed: int = 0) -> None:
    """Random files of the given sizes (paths relative to ``root``, folders made)."""
    rng = random.Random(seed)
    for name, size in sizes.items():
        p = root / name
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(rng.randbytes(size))


def sha(path: Path) -> str:
    """Hex SHA-256 of a whole file."""
    return hashlib.sha256(path.read_bytes()).hexdigest()
