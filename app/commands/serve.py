"""``gaitrig serve``: the API server, console, node websocket and 3D view."""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

HELP = "run the server (console, REST API, node websocket, 3D view)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--host", help="interface to listen on (default from GAITRIG_HOST)")
    parser.add_argument("--port", type=int, help="API/console port (default 8000)")
    parser.add_argument("--viewer-port", type=int, help="3D view port (default 8081)")
    parser.add_argument("--no-viewer", action="store_true", help="do not start the 3D view")
    parser.add_argument("--data-dir", type=Path, help="server data folder (default ./var)")
    parser.add_argument("--token", help="node pairing token (default GAITRIG_NODE_TOKEN)")
    parser.add_argument("--log-level", default="info",
                        choices=["debug", "info", "warning", "error"])


def build_settings(args: argparse.Namespace) -> object:
    """Settings from the environment overridden by the flags that were given."""
    from app.config import Settings

    over: dict[str, object] = {}
    for flag, field in [("host", "host"), ("port", "port"), ("viewer_port", "viewer_port"),
                        ("data_dir", "data_dir"), ("token", "node_token")]:
        v = getattr(args, flag, None)
        if v is not None:
            over[field] = v
    if getattr(args, "no_viewer", False):
        over["viewer_enabled"] = False
    return Settings(**over)  # type: ignore[arg-type]


def run(args: argparse.Namespace) -> int:
    import uvicorn

    from app.config import Settings
    from app.main import create_app

    settings = build_settings(args)
    assert isinstance(settings, Settings)
    logging.basicConfig(level=args.log_level.upper(),
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    from engine.errors import GaitrigError

    try:
        app = create_app(settings)
    except GaitrigError as e:  # unsafe settings for the network: say what to change
        print(f"gaitrig serve: {e}", file=sys.stderr)
        return 2
    print(f"gaitrig server on http://{settings.host}:{settings.port}/ "
          f"(nodes connect to ws://{settings.host}:{settings.port}/ws/node)", flush=True)
    # ws_per_message_deflate off: what goes over the websockets is compressed already (the
    # 3D view's zstd + float arrays, PNG/JPEG images); deflating it again cost the server
    # CPU and ~25 ms per 3D-view message (bench/viewer_proxy.py)
    uvicorn.run(app, host=settings.host, port=settings.port, log_level=args.log_level,
                ws_per_message_deflate=False, proxy_headers=True,
                forwarded_allow_ips=settings.forwarded_allow_ips,
                ws_max_size=settings.ws_transport_max_bytes, ws_ping_interval=10,
                ws_ping_timeout=20, timeout_graceful_shutdown=3)
    return 0
