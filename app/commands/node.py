"""``gaitrig node``: one sensor-node agent (one per depth sensor / mini-PC)."""

from __future__ import annotations

import argparse
import asyncio
import logging
import signal
import sys
from pathlib import Path

HELP = "run a sensor node agent that connects to the server"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--id", required=True, help="sensor id, e.g. S1")
    parser.add_argument("--backend", default="sim", choices=["sim", "replay", "k4a"],
                        help="sensor backend (default: sim)")
    parser.add_argument("--server", default="ws://127.0.0.1:8000",
                        help="server address, e.g. ws://HOST:8000 (default local)")
    parser.add_argument("--token", help="pairing token (default GAITRIG_NODE_TOKEN)")
    parser.add_argument("--data-dir", type=Path,
                        help="node folder (default <GAITRIG_DATA_DIR>/nodes/<id>)")
    parser.add_argument("--ring-seconds", type=float, default=2.0, help="ring buffer length")
    parser.add_argument("--log-level", default="info",
                        choices=["debug", "info", "warning", "error"])
    sim = parser.add_argument_group("sim backend")
    sim.add_argument("--rig", type=Path, help="rig file (TOML/JSON; default: the paper's avenue)")
    sim.add_argument("--seed", type=int, default=0, help="rig and walker seed")
    sim.add_argument("--clock-offset", type=float, help="override the sensor clock offset (s)")
    sim.add_argument("--clock-drift-ppm", type=float, help="override the clock drift (ppm)")
    sim.add_argument("--no-images", action="store_true",
                     help="skeletons only; never render images (light CPU load)")
    sim.add_argument("--report-true-clock", action="store_true",
                     help="TEST ONLY: report the simulated true clock offset in status")
    sim.add_argument("--test-warning", metavar="TEXT",
                     help="TEST ONLY: raise this sensor warning every 5 s, as a sensor in "
                          "trouble would (it shows on the Rig page beside the node)")
    rep = parser.add_argument_group("replay backend")
    rep.add_argument("--recording", type=Path, help="recording part folder to play back")
    rep.add_argument("--loop", action="store_true", help="replay in a loop")
    k4a = parser.add_argument_group("k4a backend")
    k4a.add_argument("--device", type=int, default=0, help="device index")
    k4a.add_argument("--body-tracking", default="gpu",
                     choices=["gpu", "cuda", "directml", "tensorrt", "cpu", "off"],
                     help="Body Tracking SDK processing mode: gpu (default; the SDK's GPU "
                          "runtime, CPU if none starts), cuda, directml (Windows), tensorrt, "
                          "cpu, or off (images only, no skeletons)")
    k4a.add_argument("--sensor-orientation", default="default",
                     choices=["default", "clockwise90", "counterclockwise90", "flip180"],
                     help="how the sensor is mounted, for the body tracker (default: "
                          "upright; flip180: upside down)")


def server_url(address: str) -> str:
    """``ws://host:port`` → ``ws://host:port/ws/node`` (full paths are kept)."""
    a = address.rstrip("/")
    if "://" not in a:
        a = "ws://" + a
    a = a.replace("http://", "ws://").replace("https://", "wss://")
    return a if a.endswith("/ws/node") else a + "/ws/node"


def make_backend(args: argparse.Namespace) -> object:
    """The backend the flags ask for."""
    if args.backend == "sim":
        from app.nodes.backends.sim import SimBackend

        return SimBackend(args.id, rig_path=args.rig, seed=args.seed,
                          clock_offset_s=args.clock_offset, clock_drift_ppm=args.clock_drift_ppm,
                          images=not args.no_images, report_truth=args.report_true_clock,
                          test_warning=args.test_warning)
    if args.backend == "replay":
        from app.nodes.backends.replay import ReplayBackend

        if args.recording is None:
            raise SystemExit("gaitrig node: --backend replay needs --recording FOLDER")
        return ReplayBackend(args.recording, loop=args.loop)
    from app.nodes.backends.k4a import K4ABackend

    mode = args.body_tracking
    return K4ABackend(device=args.device, body_tracking=mode != "off",
                      processing_mode="gpu" if mode == "off" else mode,
                      sensor_orientation=args.sensor_orientation)


def run(args: argparse.Namespace) -> int:
    from app.config import Settings
    from app.nodes.agent import NodeAgent, NodeRefusedError
    from app.nodes.backends.base import Backend
    from app.nodes.store import RetentionPolicy
    from engine.errors import GaitrigError

    logging.basicConfig(level=args.log_level.upper(),
                        format=f"%(asctime)s %(levelname)s node {args.id}: %(message)s")
    settings = Settings()
    try:
        backend = make_backend(args)
    except GaitrigError as exc:
        print(f"gaitrig node: {exc}", file=sys.stderr)
        return 2
    assert isinstance(backend, Backend)
    data_dir = args.data_dir or settings.data_dir / "nodes" / args.id
    retention = RetentionPolicy(keep_verified_s=settings.node_keep_verified_days * 86400.0,
                                min_free_bytes=int(settings.node_min_free_gb * 1024**3),
                                min_free_fraction=settings.node_min_free_percent / 100.0)
    agent = NodeAgent(args.id, backend, server_url(args.server), args.token or settings.node_token,
                      data_dir, ring_seconds=args.ring_seconds,
                      report_true_clock=args.report_true_clock, retention=retention)

    async def main() -> None:
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, agent.stop)
        await agent.run()

    try:
        asyncio.run(main())
    except NodeRefusedError as exc:
        print(f"gaitrig node: {exc}", file=sys.stderr)
        return 3
    except GaitrigError as exc:
        print(f"gaitrig node: {exc}", file=sys.stderr)
        return 2
    return 0
