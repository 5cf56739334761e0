"""The service's settings: one pydantic-settings class read from INTSPACE_* variables and .env."""

from __future__ import annotations

from functools import cached_property
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, SecretStr, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

# An MQTT topic prefix: levels of letters, digits, "_" and "-", no wildcard, no empty level.
_TOPIC_PREFIX = r"^[A-Za-z0-9_-]+(/[A-Za-z0-9_-]+)*$"


class FrigateCamera(BaseModel):
    """A Frigate camera fed to the tracker: the intspace camera it is, and Frigate's detect
    resolution (its boxes' pixels)."""

    model_config = ConfigDict(extra="forbid")

    camera: str = Field(min_length=1, max_length=200)
    detect: tuple[int, int] = Field(description="Frigate's detect width and height, pixels.")

    @field_validator("detect")
    @classmethod
    def _positive(cls, value: tuple[int, int]) -> tuple[int, int]:
        if min(value) < 1 or max(value) > 100_000:
            raise ValueError("detect must be [width, height] in pixels, 1 to 100000")
        return value


class Settings(BaseSettings):
    """Everything the service can be configured with; each field is INTSPACE_<NAME> in the env."""

    model_config = SettingsConfigDict(
        env_prefix="INTSPACE_",
        env_file=".env",
        extra="ignore",
        frozen=True,
        # A refused value is not quoted: it may be a broker URL with its password.
        hide_input_in_errors=True,
    )

    data_dir: Path = Field(Path("var"), description="Where the default SQLite file lives.")
    database_url: SecretStr | None = Field(
        None, description="Any SQLAlchemy URL; default: a SQLite file under data_dir."
    )
    admin_token: SecretStr | None = Field(
        None, description="When set, this is the admin token and none is generated."
    )
    public_reads: bool = Field(False, description="Reads need no token.")
    cors_origins: list[str] = Field(
        default_factory=list, description="Origins allowed by CORS; empty closes CORS."
    )
    session_ttl_s: float = Field(
        12 * 3600.0, ge=60, le=30 * 86400, description="Life of a dashboard sign-in (s)."
    )
    auth_failure_limit: str = Field(
        "10/minute",
        pattern=r"^\d+ ?(/|per) ?\d* ?(second|minute|hour|day)s?$",
        description="Failed authentications per client before 429 (`limits` notation).",
    )

    host: str = Field(
        "127.0.0.1", min_length=1, description="Interface `intspace serve` binds (--host wins)."
    )
    port: int = Field(8000, ge=1, le=65535, description="API port (--port wins).")
    # Several `intspace serve` processes on one PostgreSQL database: exactly one runs the 3D
    # scene and the twin (the defaults); the others set viser_enabled and simulation false.
    viser_enabled: bool = Field(
        True, description="Run the 3D scene (viser) in this process; false on all but one."
    )
    viser_port: int = Field(8080, ge=1, le=65535)
    simulation: bool = Field(
        False,
        description="Run the digital twin so the space is alive (in one process only, where "
        "several share a PostgreSQL database).",
    )
    twin_rate_hz: float = Field(
        5.0, ge=0.5, le=30, description="Frames per second of the twin (0.5 to 30)."
    )
    twin_seed: int = Field(0, ge=0, description="Seed of the twin's noise and motion.")
    twin_detection: Literal["internal", "external"] = Field(
        "internal",
        description="internal: the twin detects in its frames and feeds the tracker; "
        "external: it only renders, and camera nodes (`intspace node`) read its streams "
        "(/cameras/{id}/stream.mjpg) and post the detections.",
    )
    targets_flush_hz: float = Field(
        2.0, gt=0, le=20, description="How often live targets are written to the database."
    )
    track_points_hz: float = Field(
        20.0, ge=1, le=100, description="Track points stored per second per target, at most."
    )
    # A home with three people tracked at 20 points a second stores ~5 M points a day; four
    # cameras at 5 Hz a million detections an hour: the defaults keep a day and an hour.
    track_retention_s: float = Field(
        86400.0, gt=0, description="Track points and ended targets kept this long (s)."
    )
    detection_retention_s: float = Field(
        3600.0, gt=0, description="Stored detections kept this long (s)."
    )
    tracker_latency_s: float = Field(
        1.0,
        ge=0,
        le=5,
        description="The longest the tracker waits for a camera's late frames (s): frames are "
        "put in time order within this window, and released sooner once every camera heard "
        "from within it has delivered frames as recent. Above the cameras' delay (stream, node "
        "and network: 0.3-1 s for RTSP cameras); a frame later than that is refused as late.",
    )

    # Home integration (spec 09): MQTT, Home Assistant discovery, Frigate as a source.
    mqtt_url: SecretStr | None = Field(
        None,
        description="The MQTT broker the service publishes to (mqtt://user:password@host:1883, "
        "mqtts:// for TLS); unset: no MQTT. A secret: shown with its password masked.",
    )
    mqtt_prefix: str = Field(
        "intspace", pattern=_TOPIC_PREFIX, description="The first level of every topic."
    )
    mqtt_discovery_prefix: str = Field(
        "homeassistant", pattern=_TOPIC_PREFIX, description="Home Assistant's discovery prefix."
    )
    mqtt_target_hz: float = Field(
        2.0, ge=0, le=30, description="Messages per second per target at most (0: none)."
    )
    mqtt_queue: int = Field(
        10_000, ge=10, le=1_000_000, description="Messages waiting for a slow or absent broker."
    )
    frigate_mqtt: SecretStr | None = Field(
        None,
        description="The broker Frigate publishes to (mqtt://user:password@host:1883); unset: "
        "Frigate is not a source. A secret, like mqtt_url.",
    )
    frigate_cameras: dict[str, FrigateCamera] = Field(
        default_factory=dict,
        description='Frigate cameras fed to the tracker: JSON {"frigate name": {"camera": '
        '"intspace camera name", "detect": [width, height]}}.',
    )
    frigate_labels: str = Field(
        "person", min_length=1, description="Frigate labels taken, comma separated."
    )
    frigate_timeout_s: float = Field(
        60.0, gt=0, le=3600, description="A Frigate object without news for this long has left."
    )
    frigate_topic_prefix: str = Field(
        "frigate", pattern=_TOPIC_PREFIX, description="Frigate's MQTT topic prefix."
    )

    run_workers: int = Field(2, ge=1, le=64, description="Threads executing calibration runs.")
    run_executor: Literal["local", "external"] = Field(
        "local",
        description="local: runs execute in this process; external: `intspace worker` "
        "processes claim them from the database.",
    )
    # A claim is a lease its worker renews by heartbeat: a worker that dies (SIGKILL, power
    # loss) stops renewing, and its run goes back to the queue once the lease has expired.
    run_lease_s: float = Field(
        30.0, ge=0.5, le=3600, description="How long a claim on a run lasts unrenewed (s)."
    )
    run_heartbeat_s: float = Field(
        5.0, ge=0.1, le=600, description="How often a worker renews its claims (s)."
    )
    run_max_attempts: int = Field(
        3, ge=1, le=100, description="Claims of a run before it is given up, with the reason."
    )

    max_request_bytes: int = Field(64 * 2**20, ge=1024, description="Whole request body cap.")
    max_upload_file_bytes: int = Field(16 * 2**20, ge=1024, description="Per uploaded image.")
    max_upload_files: int = Field(60, ge=1, description="Images per calibration upload.")
    # 12 MP decode to 36 MB of BGR (96 MB as 16-bit RGBA): one upload stays under 150 MB.
    max_image_pixels: int = Field(
        12_000_000, ge=1, description="Pixels per uploaded image, read from its header."
    )
    export_max_range_s: float = Field(
        3600.0, gt=0, description="The longest time range one GET /spaces/{id}/export.mcap spans."
    )

    @field_validator("mqtt_url", "frigate_mqtt")
    @classmethod
    def _broker_url(cls, value: SecretStr | None) -> SecretStr | None:
        if value is not None:
            from server.services.comms.mqtt import BrokerUrl

            BrokerUrl.parse(value.get_secret_value())  # its errors never quote the password
        return value

    @cached_property
    def resolved_database_url(self) -> str:
        """Return the database URL, the default SQLite file under data_dir when none is set."""
        if self.database_url is not None:
            return self.database_url.get_secret_value()
        return f"sqlite:///{(self.data_dir / 'intspace.sqlite3').resolve()}"

    @property
    def database_backend(self) -> str:
        """Return "sqlite" or "postgresql" (the SQLAlchemy dialect name)."""
        from sqlalchemy.engine import make_url

        return make_url(self.resolved_database_url).get_backend_name()

    def masked(self) -> dict[str, object]:
        """Return the settings with secrets (tokens, database password) masked, for printing."""
        from sqlalchemy.engine import make_url

        values: dict[str, object] = {}
        for name in type(self).model_fields:
            value = getattr(self, name)
            if isinstance(value, SecretStr):
                value = "**********"
            values[name] = value
        url = make_url(self.resolved_database_url)
        values["database_url"] = url.render_as_string(hide_password=True)
        from server.services.comms.mqtt import BrokerUrl

        for name in ("mqtt_url", "frigate_mqtt"):
            secret = getattr(self, name)
            if secret is not None:
                values[name] = BrokerUrl.parse(secret.get_secret_value()).redacted()
        return values
