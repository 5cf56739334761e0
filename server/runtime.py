"""What one service process holds while it runs: its settings, database, caches and the services
start-up starts. Built once by `server.app.create_app` (the parts that need nothing started) and
completed by its lifespan (the services that run threads: executor, tracker, twin, ...); routes
receive its parts as typed dependencies from `server.api.deps`."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from sqlalchemy import Engine
from sqlalchemy.orm import Session, sessionmaker

from server.db.session import make_engine, make_session_factory
from server.security import AuthFailureLimiter
from server.services.auth import TokenCache
from server.services.camera_health import CameraHealthBook
from server.services.frames import LatestFrames
from server.services.path_following import FollowTasks
from server.services.scene_sync import SceneSync
from server.services.targets import LiveTargets
from server.settings import Settings

if TYPE_CHECKING:
    from server.services.comms.frigate import FrigateSource
    from server.services.comms.home import HomePublisher
    from server.services.manipulation import TaskRunner
    from server.services.runs import RunExecutor
    from server.services.tracking import TrackingService
    from server.services.twin import Twin
    from server.services.zones import ZoneService

# viser listens on loopback only: the API proxies the scene behind its credentials.
VISER_HOST = "127.0.0.1"


@dataclass
class Runtime:
    """The service's state: what `create_app` builds, then what its lifespan starts (None until
    it has, or when the settings leave it off)."""

    settings: Settings
    engine: Engine
    session_factory: sessionmaker[Session]
    targets: LiveTargets
    auth_limiter: AuthFailureLimiter
    scene_sync: SceneSync = field(default_factory=lambda: SceneSync(None))
    token_cache: TokenCache = field(default_factory=TokenCache)
    latest_frames: LatestFrames = field(default_factory=LatestFrames)
    camera_health: CameraHealthBook = field(default_factory=CameraHealthBook)
    viser_host: str = VISER_HOST
    viser_port: int = 0
    # Started by the lifespan.
    executor: RunExecutor | None = None
    tracking: TrackingService | None = None
    zones: ZoneService | None = None
    home: HomePublisher | None = None
    frigate: FrigateSource | None = None
    twin: Twin | None = None
    task_runner: TaskRunner | None = None
    follow_tasks: FollowTasks | None = None

    @classmethod
    def build(cls, settings: Settings) -> Runtime:
        """Return the runtime of `settings` before start-up: database engine and sessions,
        caches, live targets that nothing feeds yet, no scene."""
        engine = make_engine(settings.resolved_database_url)
        factory = make_session_factory(engine)
        return cls(
            settings=settings,
            engine=engine,
            session_factory=factory,
            targets=LiveTargets(factory),
            auth_limiter=AuthFailureLimiter(settings.auth_failure_limit),
            viser_port=settings.viser_port,
        )
