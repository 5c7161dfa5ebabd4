"""Memory of a node agent against the length of a recording.

Drives :class:`app.nodes.agent.NodeAgent` frame by frame (no server, no real time: a
scripted backend) through a short and a ten-times longer recording at 30 fps, with a
small depth image recorded for every tenth frame, and measures with ``tracemalloc`` the
Python memory the agent still holds at the end of each (before the stop; the store on a
temporary folder). A node whose memory does not grow with the recording has a ratio
long/short near 1 (the peer is the short recording, measured in the same run). Prints
one JSON line.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
import tracemalloc
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.nodes.agent import NodeAgent  # noqa: E402
from app.nodes.backends.base import Backend, Frame  # noqa: E402
from app.nodes.protocol import RecStart, RecStop, SensorInfo  # noqa: E402


class _Scripted(Backend):
    name = "scripted"

    def open(self) -> SensorInfo:
        return SensorInfo()

    def frames(self) -> Iterator[Frame]:
        return iter(())

    def now(self) -> float:
        return time.time()


def _images(streams: Sequence[str]) -> dict[str, np.ndarray]:
    return {"depth": np.full((48, 64), 1500, np.uint16)}


def held_after(n_frames: int) -> tuple[int, float]:
    """Bytes the agent holds after recording ``n_frames`` frames, and the seconds taken."""
    with tempfile.TemporaryDirectory() as tmp:
        agent = NodeAgent("S1", _Scripted(), "ws://127.0.0.1:1/ws/node", "t", tmp)
        pos = np.zeros((1, 25, 3), np.float32)
        st = np.full((1, 25), 2, np.uint8)
        tracemalloc.start()
        t0 = time.perf_counter()
        agent._on_command(RecStart(rec_id="R1", t_start_server=0.0, t_start_local=0.0,
                                   streams=["depth"], image_every=10))
        for k in range(n_frames):
            agent._on_frame(Frame(k / 30.0, pos, st, [0], _images))
        agent._pool.submit(lambda: None).result()  # the images queued so far are written
        held = tracemalloc.get_traced_memory()[0]
        seconds = time.perf_counter() - t0
        tracemalloc.stop()
        agent._on_command(RecStop(rec_id="R1", t_stop_server=0.0, t_stop_local=n_frames / 30))
        agent._on_frame(Frame(n_frames / 30.0 + 1, pos, st, [0], _images))
        agent._pool.shutdown(wait=True)
    return held, seconds


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=2.0, help="the short recording")
    args = ap.parse_args()
    n = int(args.minutes * 60 * 30)
    short, t_short = held_after(n)
    long, t_long = held_after(10 * n)
    print(json.dumps({"bench": "node_memory", "short_minutes": args.minutes,
                      "long_minutes": 10 * args.minutes, "held_short_bytes": short,
                      "held_long_bytes": long, "ratio_long_short": round(long / short, 3),
                      "seconds": round(t_short + t_long, 1)}))


if __name__ == "__main__":
    main()
