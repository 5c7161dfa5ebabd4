"""A tiny tmpfs for tests of a full disk (skipped, or done without, when there is no root
or no mount command)."""

from __future__ import annotations

import os
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest


@contextmanager
def _tmpfs(mnt: Path, size: str) -> Iterator[str | None]:
    """Mount a tmpfs of ``size`` on ``mnt`` (created) for the block, which gets why it
    could not be mounted, or None; unmounted after it."""
    mnt.mkdir(parents=True, exist_ok=True)
    if os.geteuid() != 0:
        yield "mounting a tmpfs needs root"
        return
    try:
        r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(mnt)],
                           capture_output=True, text=True)
    except FileNotFoundError:
        yield "no mount command to create a small tmpfs"
        return
    if r.returncode != 0:
        yield f"cannot mount a tmpfs here: {r.stderr.strip()}"
        return
    try:
        yield None
    finally:
        subprocess.run(["umount", "-l", str(mnt)], check=False, capture_output=True)


@contextmanager
def mounted_tmpfs(mnt: Path, size: str) -> Iterator[Path]:
    """Mount a tmpfs of ``size`` (e.g. ``"64k"``) on ``mnt`` (created) for the block; the
    test is skipped, saying why, where it cannot be mounted."""
    with _tmpfs(mnt, size) as why:
        if why is not None:
            pytest.skip(why)
        yield mnt


@contextmanager
def tmpfs_if_possible(mnt: Path, size: str) -> Iterator[Path | None]:
    """As :func:`mounted_tmpfs` for a test whose full-disk part is optional: where the
    tmpfs cannot be mounted the block gets None (and ``mnt`` is a plain folder)."""
    with _tmpfs(mnt, size) as why:
        yield mnt if why is None else None
