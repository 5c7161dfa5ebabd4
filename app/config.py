"""Application settings: one pydantic-settings class, environment prefix ``GAITRIG_``.

Every knob of the server and of the node agents lives here so that ``gaitrig serve``,
``gaitrig node``, ``gaitrig demo`` and ``docker-compose.yml`` stay consistent: the CLI
flags only override these fields.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict

#: The shipped pairing token: anyone who read the docs can pair a node with a server that
#: still uses it, so the server warns (log and console) until it is changed.
DEFAULT_NODE_TOKEN = "change-me-node-token"


class Settings(BaseSettings):
    """Server and node configuration (override any field with ``GAITRIG_<FIELD>``)."""

    model_config = SettingsConfigDict(env_prefix="GAITRIG_", extra="ignore")

    data_dir: Path = Field(
        default=Path("./var"),
        description="Server data folder (database, recordings).",
    )
    host: str = Field(default="127.0.0.1", description="Interface the API server listens on.")
    port: int = Field(
        default=8000, ge=0, le=65535,
        description="API / console / node websocket port.",
    )
    transfer_port: int = Field(
        default=8001, ge=0, le=65535,
        description="TCP port of the transfer data channel (nodes send recording chunks "
        "to it, on the same interface as the API). If it is taken, any free port is used; "
        "0: always any free port. Nodes that cannot reach it fall back to the websocket "
        "(slower). Environment: GAITRIG_TRANSFER_PORT.",
    )
    viewer_enabled: bool = Field(
        default=True,
        description="Start the viser 3D view in the lifespan.",
    )
    viewer_host: str = Field(default="127.0.0.1", description="Interface of the viser server.")
    viewer_port: int = Field(default=8081, ge=0, le=65535, description="Port of the viser 3D view.")

    node_token: str = Field(
        default=DEFAULT_NODE_TOKEN, min_length=8,
        description="Pairing token every node must present."
    )
    admin_user: str = Field(
        default="admin", min_length=1,
        description="Admin account created on first run.",
    )
    admin_password: str | None = Field(
        default=None, description="First-run admin password; generated and printed when unset."
    )
    password_hash_cost: int = Field(
        default=17, ge=10, le=20,
        description="scrypt cost of stored console passwords as log2(N) (r = 8, p = 1). 17 is "
        "OWASP's recommendation (128 MiB and a few hundred ms per login); older hashes are "
        "re-hashed at the next login. Environment: GAITRIG_PASSWORD_HASH_COST.",
    )
    session_hours: float = Field(default=12.0, gt=0, description="Lifetime of a console login.")
    session_idle_minutes: float = Field(
        default=30.0, gt=0,
        description="A login unused this long ends (idle timeout); every authenticated "
        "request starts it over. Environment: GAITRIG_SESSION_IDLE_MINUTES.",
    )
    cookie_secure: bool | None = Field(
        default=None,
        description="Send the session cookie over HTTPS only. Unset: whenever the request "
        "came over HTTPS (directly or per X-Forwarded-Proto from a trusted proxy, "
        "GAITRIG_FORWARDED_ALLOW_IPS). Set true behind a TLS proxy that uvicorn does not "
        "trust. Environment: GAITRIG_COOKIE_SECURE.",
    )
    forwarded_allow_ips: str = Field(
        default="127.0.0.1",
        description="Addresses of reverse proxies whose X-Forwarded-Proto/-For headers "
        "are believed (uvicorn's forwarded_allow_ips): the client address in the audit "
        "trail and HTTPS for the cookie come from them. Comma-separated, '*' for any "
        "(only when nothing but the proxy can reach the port). Environment: "
        "GAITRIG_FORWARDED_ALLOW_IPS.",
    )
    allowed_origins: list[str] = Field(
        default_factory=list,
        description="Other origins (https://gait.clinic.example.org) whose pages may send "
        "state-changing requests and open websockets with the console's cookie. Needed "
        "only when a reverse proxy serves the console under a name it does not pass on "
        "as Host or X-Forwarded-Host; requests from any other origin are refused (403). "
        "Environment: GAITRIG_ALLOWED_ORIGINS='[\"https://gait.clinic.example.org\"]'.",
    )
    login_max_failures: int = Field(
        default=5, ge=1, description="Failed logins per user and address before a pause."
    )
    login_lockout_s: float = Field(
        default=300.0, ge=0, description="Window (s) of those failed logins, and the pause."
    )

    max_control_bytes: int = Field(
        default=64 * 1024, gt=0, description="Largest accepted JSON control message from a node."
    )
    max_binary_bytes: int = Field(
        default=16 * 1024 * 1024, gt=0,
        description="Largest accepted binary (frame) message from a node."
    )
    ws_transport_max_bytes: int = Field(
        default=64 * 1024 * 1024,
        gt=0,
        description="Hard websocket frame limit; above it the connection is closed (1009).",
    )

    clock_warn_ms: float = Field(
        default=2.0, gt=0,
        description="Warn when the clock uncertainty exceeds this.",
    )
    clock_ping_interval_s: float = Field(
        default=0.1, gt=0,
        description="Clock ping period per node.",
    )
    clock_window_s: float = Field(default=30.0, gt=1, description="Window of the clock drift fit.")
    record_start_margin_s: float = Field(
        default=0.3, ge=0, description="Recording starts this far after the command is issued."
    )
    health_stale_s: float = Field(
        default=3.0, gt=0,
        description="A node silent this long is marked stale.",
    )

    calibration_check_interval_s: float = Field(
        default=300.0, ge=0,
        description="Bumped-tripod check: re-detect the markers every this many seconds "
        "(while a calibration is active, all its sensors are connected and no recording "
        "is running or transferring) and warn on the Rig and Record pages when a sensor "
        "moved > 1 cm / 0.5°. 0 disables the periodic check.",
    )

    storage_check_interval_s: float = Field(
        default=3600.0, ge=0,
        description="Check that every settled recording's copy on the server is whole (its "
        "part folders hold every file of their manifest with its size) once in this many "
        "seconds, a few recordings per data-sync pass; a missing or damaged one is shown "
        "as 'Server copy missing — restore from backup' and audited. 0 disables the check.",
    )

    node_keep_verified_days: float = Field(
        default=7.0, ge=0,
        description="Node retention: a node keeps its copy of a recording part this many "
        "days after the server verified its own copy, then deletes it (0: at once). A part "
        "the server has not verified is never deleted. Environment: "
        "GAITRIG_NODE_KEEP_VERIFIED_DAYS.",
    )
    node_min_free_gb: float = Field(
        default=5.0, ge=0,
        description="Node retention: whenever a node's disk has less free space than this "
        "(or than node_min_free_percent of the disk, whichever is larger), it deletes "
        "verified parts, oldest first, before their days are up. Environment: "
        "GAITRIG_NODE_MIN_FREE_GB.",
    )
    node_min_free_percent: float = Field(
        default=10.0, ge=0, le=100,
        description="Node retention: the free-space floor as a share of the node's disk "
        "(see node_min_free_gb). Environment: GAITRIG_NODE_MIN_FREE_PERCENT.",
    )

    test_command_delay_max_s: float = Field(
        default=0.0,
        ge=0,
        le=1.9,
        description="TEST HOOK: delay every start/stop command by a random 0..this per node.",
    )

    database_url: str | None = Field(
        default=None,
        description="SQLAlchemy URL of the database, e.g. postgresql+psycopg://user:pw@host/"
        "gaitrig (needs that driver installed). Default: SQLite in the data folder.",
    )

    kscc_peers: list[str] = Field(
        default_factory=list,
        description="Other sites' gaitrig servers a KSCC two-site link may connect to: base "
        "URLs (https://lab-b.example.org:8000 — scheme, host and port must match) or "
        "host[:port] (any scheme; any port without one). Empty: no remote site. Environment: "
        "GAITRIG_KSCC_PEERS='[\"https://lab-b.example.org:8000\"]'.",
    )

    @property
    def db_path(self) -> Path:
        """SQLite database file (used when no database_url is set)."""
        return self.data_dir / "gaitrig.sqlite3"

    @property
    def db_url(self) -> str:
        """The database to open: ``database_url`` or the SQLite file."""
        return self.database_url or f"sqlite:///{self.db_path}"


@lru_cache(maxsize=1)
def get_settings() -> Settings:
    """Settings read once from the environment (FastAPI dependency)."""
    return Settings()
