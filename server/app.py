"""The FastAPI application: API routers under /api/v1, the dashboard at /, the run executor and
the live 3D scene started and stopped with the app."""

from __future__ import annotations

import gc
import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import TYPE_CHECKING

from fastapi import APIRouter, FastAPI
from fastapi.middleware.cors import CORSMiddleware
from fastapi.staticfiles import StaticFiles
from starlette.concurrency import run_in_threadpool

import server
from server.api import (
    arms,
    calibration_runs,
    cameras,
    export,
    home,
    landmarks,
    maps,
    observations,
    paths,
    placement,
    projectors,
    robots,
    rooms,
    scene_proxy,
    semantic_maps,
    session,
    spaces,
    streams,
    system,
    targets,
    tasks,
    tokens,
    twin,
    zones,
)
from server.api.errors import install_api_fallback, install_error_handlers
from server.api.limits import RequestSizeLimit
from server.api.server_time import ServerTime
from server.runtime import Runtime
from server.schemas.registry import CameraHeartbeat
from server.security import SecurityHeaders, install_log_redaction
from server.services.calibration import RunRefused
from server.services.camera_health import CameraHealthBook
from server.services.comms.frigate import FrigateSource
from server.services.comms.home import HomePublisher
from server.services.comms.mqtt import BrokerUrl, MqttLink
from server.services.jobs import LeasePolicy
from server.services.ownership import SpaceLocks
from server.services.path_following import FollowTasks
from server.services.runs import RunExecutor
from server.services.scene_sync import SceneSync
from server.services.survey import TwinTaskRunner
from server.services.targets import LiveTargets
from server.services.tracking import TrackingService
from server.services.zones import ZoneService
from server.settings import Settings
from server.version import VERSION

if TYPE_CHECKING:
    from server.services.twin import Twin

log = logging.getLogger(__name__)

API_PREFIX = "/api/v1"
WEB_DIR = Path(server.__file__).resolve().parent.parent / "web"


def api_router() -> APIRouter:
    """Return the router of every /api/v1 resource."""
    router = APIRouter(prefix=API_PREFIX)
    for module in (
        system,
        spaces,
        rooms,
        cameras,
        projectors,
        paths,
        robots,
        arms,
        landmarks,
        calibration_runs,
        placement,
        tasks,
        tokens,
        session,
        observations,
        targets,
        maps,
        semantic_maps,
        twin,
        streams,
        export,
        home,
        scene_proxy,
        zones,
    ):
        router.include_router(module.router)
    return router


def _start_twin(runtime: Runtime, tracking: TrackingService) -> Twin:
    from core.sim import default_scene
    from server.services.twin import Twin

    settings = runtime.settings
    twin = Twin(
        default_scene(),
        runtime.session_factory,
        runtime.targets,
        tracking,
        runtime.scene_sync,
        rate_hz=settings.twin_rate_hz,
        seed=settings.twin_seed,
        detect=settings.twin_detection == "internal",
        health=runtime.camera_health,
    )
    twin.bootstrap()
    return twin


def _start_home(
    settings: Settings,
    factory,
    tracking: TrackingService,
    zone_service: ZoneService,
    book: CameraHealthBook,
) -> tuple[HomePublisher | None, FrigateSource | None, MqttLink | None]:
    """Start what talks to the home (spec 09): the MQTT publisher when INTSPACE_MQTT_URL is
    set, Frigate as a source when INTSPACE_FRIGATE_MQTT and its cameras are."""
    publisher = None
    if settings.mqtt_url is not None:
        link = MqttLink(
            BrokerUrl.parse(settings.mqtt_url.get_secret_value()), queue_limit=settings.mqtt_queue
        )
        shared = settings.database_backend == "postgresql"
        publisher = HomePublisher(
            link,
            prefix=settings.mqtt_prefix,
            discovery_prefix=settings.mqtt_discovery_prefix,
            target_hz=settings.mqtt_target_hz,
            factory=factory,
            health_of=lambda camera_id: book.health(camera_id).model_dump(),
            owns=tracking.owns,
            available_lock=SpaceLocks(settings.resolved_database_url) if shared else None,
        )
        zone_service.sinks.append(publisher)
        publisher.start()
        print(
            f"MQTT: publishing to {link.url.redacted()} under {settings.mqtt_prefix}/", flush=True
        )
    frigate = frigate_link = None
    if settings.frigate_mqtt is not None and settings.frigate_cameras:

        def heartbeat(camera_id: int, fps: float, last_frame_t: float | None) -> None:
            book.beat(camera_id, CameraHeartbeat(fps=fps, last_frame_t=last_frame_t))

        frigate = FrigateSource(
            factory,
            tracking,
            settings.frigate_cameras,
            labels=settings.frigate_labels,
            timeout_s=settings.frigate_timeout_s,
            topic_prefix=settings.frigate_topic_prefix,
            heartbeat=heartbeat,
        )
        frigate_link = MqttLink(
            BrokerUrl.parse(settings.frigate_mqtt.get_secret_value()),
            subscriptions=frigate.subscriptions,
            on_message=frigate.on_message,
        )
        frigate.start()
        frigate_link.start()
        frigate.link = frigate_link
        print(
            f"Frigate: reading {frigate_link.url.redacted()} ({len(settings.frigate_cameras)} "
            "camera(s))",
            flush=True,
        )
    return publisher, frigate, frigate_link


def create_app(settings: Settings | None = None) -> FastAPI:
    """Return the service's app. The database schema must be at head already (`intspace serve`
    and `intspace db upgrade` migrate it)."""
    settings = settings or Settings()
    runtime = Runtime.build(settings)
    engine = runtime.engine
    factory = runtime.session_factory

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        # After uvicorn configured its loggers: no token reaches a log line.
        install_log_redaction(
            [settings.admin_token.get_secret_value()] if settings.admin_token else []
        )
        executor = None
        if settings.run_executor == "local":
            # Queued runs stay queued; runs whose worker died go back to the queue once their
            # lease expires (the executor's first poll re-queues those already expired).
            executor = RunExecutor(
                factory, settings.run_workers, LeasePolicy.from_settings(settings)
            )
        runtime.executor = executor
        scene = None
        if settings.viser_enabled:
            from server.scene import SceneService

            # Loopback only: the API proxies the scene behind its credentials.
            scene = SceneService(runtime.viser_host, settings.viser_port)
            await run_in_threadpool(scene.start)
            runtime.viser_port = scene.port
            if scene.port != settings.viser_port:
                # viser moves to a free port when the configured one is taken; say where it went
                # so the address printed at start-up is not the last word.
                print(
                    f"3D scene (viser): port {settings.viser_port} is in use; the scene is on "
                    f"port {scene.port} instead",
                    flush=True,
                )
        runtime.scene_sync = SceneSync(scene)
        live = LiveTargets(
            factory,
            flush_hz=settings.targets_flush_hz,
            track_hz=settings.track_points_hz,
            track_retention_s=settings.track_retention_s,
            detection_retention_s=settings.detection_retention_s,
        )
        runtime.targets = live
        # On PostgreSQL several processes share the spaces' trackers (one per space, taken
        # over with its live targets when its process dies): live targets are not stale there.
        shared = settings.database_backend == "postgresql"
        if not shared:
            with factory() as session:
                live.close_stale(session)
        tracking = TrackingService(
            factory,
            live,
            latency=settings.tracker_latency_s,
            shared_database_url=settings.resolved_database_url if shared else None,
        )
        runtime.tracking = tracking
        zone_service = ZoneService(
            factory,
            owns=tracking.owns,
            live_xy=lambda space_id: [
                (v["kind"], v["xy"])
                for v in live.snapshot()[1]
                if v["space_id"] == space_id and v["state"] in ("confirmed", "coasting")
            ],
        )
        tracking.target_listeners.append(zone_service.on_targets)
        zone_service.attach_tracking(tracking)
        runtime.zones = zone_service
        publisher, frigate, frigate_link = _start_home(
            settings, factory, tracking, zone_service, runtime.camera_health
        )
        runtime.home = publisher
        runtime.frigate = frigate
        twin = None
        if settings.simulation:
            twin = await run_in_threadpool(_start_twin, runtime, tracking)
        runtime.twin = twin
        task_runner = await run_in_threadpool(
            TwinTaskRunner, factory, scene=runtime.scene_sync, twin=twin
        )
        runtime.task_runner = task_runner
        follow_tasks = FollowTasks(factory)
        runtime.follow_tasks = follow_tasks
        with factory() as session:
            runtime.scene_sync.load(session)
        live.start()
        zone_service.start()
        tracking.start()
        if twin is not None:
            twin.start()
            print(
                f"Digital twin: running {twin.scene.name!r} at {settings.twin_rate_hz:g} Hz "
                f"({len(twin.camera_ids)} cameras, space {twin.space_id})",
                flush=True,
            )
        # What start-up made (modules, the app, the twin's scene) lives as long as the process.
        # Frozen, it is left out of the full collections, which otherwise walk it all every
        # few seconds under load: 145 ms pauses that were the whole tail of a read's latency.
        gc.collect()
        gc.freeze()
        try:
            yield
        finally:
            if twin is not None:
                await run_in_threadpool(twin.stop)
            await run_in_threadpool(task_runner.shutdown)
            await run_in_threadpool(follow_tasks.shutdown)
            if frigate_link is not None:
                await run_in_threadpool(frigate_link.stop)
            if frigate is not None:
                await run_in_threadpool(frigate.stop)
            await run_in_threadpool(tracking.stop)
            await run_in_threadpool(zone_service.stop)
            if publisher is not None:
                # After the tracker: the last events go out, then `offline`.
                await run_in_threadpool(publisher.stop)
            await run_in_threadpool(live.stop)
            if executor is not None:
                interrupted = await run_in_threadpool(executor.shutdown)
                if interrupted:
                    log.warning("handed %d calibration run(s) back to the queue", interrupted)
            if scene is not None:
                await run_in_threadpool(scene.stop)
            engine.dispose()
            # Collectable again: a process that makes several apps (tests) does not keep them.
            gc.unfreeze()

    app = FastAPI(
        title="intspace",
        version=VERSION,
        summary="Registry, calibration runs and live scene of a home intelligent space.",
        lifespan=lifespan,
        openapi_url=f"{API_PREFIX}/openapi.json",
        docs_url=None,  # served from the package by server.api.system
        redoc_url=None,
    )
    # The one thing on app.state: server.api.deps hands its parts to the routes.
    app.state.runtime = runtime

    install_error_handlers(app)
    app.add_exception_handler(RunRefused, calibration_runs.answer_refused)
    app.include_router(api_router())
    install_api_fallback(app, API_PREFIX)
    if settings.cors_origins:
        app.add_middleware(
            CORSMiddleware,
            allow_origins=settings.cors_origins,
            allow_methods=["*"],
            allow_headers=["Authorization", "Content-Type"],
        )
    app.add_middleware(RequestSizeLimit, max_bytes=settings.max_request_bytes)
    app.add_middleware(SecurityHeaders)
    app.add_middleware(ServerTime)
    app.add_api_route("/docs", system.docs_redirect, include_in_schema=False)
    # Mounted last so that /api/v1 wins over the static files.
    if WEB_DIR.is_dir():
        app.mount("/", StaticFiles(directory=WEB_DIR, html=True), name="web")
    return app
