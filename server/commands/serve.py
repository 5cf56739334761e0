"""`intspace serve`: migrate, print where everything is, run the API with uvicorn.
`intspace worker`: execute queued calibration runs from the shared database."""

from __future__ import annotations

import argparse
import logging
import sys
import threading

from server.commands._signals import stop_on_signals
from server.settings import Settings


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `serve` and `worker` commands."""
    serve = subparsers.add_parser("serve", help="Run the web service (API, dashboard, 3D scene).")
    serve.add_argument("--host", help="Interface to bind (default: INTSPACE_HOST, else 127.0.0.1).")
    serve.add_argument("--port", type=int, help="API port (default: INTSPACE_PORT, else 8000).")
    serve.add_argument("--log-level", default="info", help="uvicorn log level.")
    serve.set_defaults(func=run_serve)
    worker = subparsers.add_parser(
        "worker", help="Execute queued calibration runs (with INTSPACE_RUN_EXECUTOR=external)."
    )
    worker.add_argument("--poll", type=float, default=1.0, help="Seconds between queue polls.")
    worker.set_defaults(func=run_worker)


def _prepare_database(settings: Settings) -> str | None:
    """Migrate to head and create the first-run admin token; return that token, if created."""
    from server.db.migrate import upgrade_to_head
    from server.db.session import make_engine, make_session_factory
    from server.services.auth import ensure_admin_token

    settings.data_dir.mkdir(parents=True, exist_ok=True)
    engine = make_engine(settings.resolved_database_url, pool_size=1)
    try:
        backup = upgrade_to_head(engine, settings.resolved_database_url)
        if backup is not None:
            print(f"Database backed up to {backup} before migrating", flush=True)
        configured = settings.admin_token.get_secret_value() if settings.admin_token else None
        with make_session_factory(engine)() as session:
            return ensure_admin_token(session, configured)
    finally:
        engine.dispose()


def _browser_host(host: str) -> str:
    if host in ("0.0.0.0", "::", ""):
        return "127.0.0.1"
    return f"[{host}]" if ":" in host else host


def run_serve(args: argparse.Namespace) -> int:
    """Run the service until interrupted; return the exit code."""
    import uvicorn
    from sqlalchemy.exc import SQLAlchemyError

    from server.app import create_app

    settings = Settings()
    bind = args.host if args.host is not None else settings.host
    port = args.port if args.port is not None else settings.port
    from server.services.auth import admin_token_problem

    if (problem := admin_token_problem(settings.admin_token)) is not None:
        print(f"intspace serve: {problem}", file=sys.stderr, flush=True)
        return 2
    print("Settings:", flush=True)
    for name, value in settings.masked().items():
        print(f"  {name} = {value}", flush=True)
    try:
        token = _prepare_database(settings)
    except (OSError, SQLAlchemyError) as exc:
        # One line that names the storage, not a traceback: the data directory or database
        # cannot be opened, created or migrated.
        reason = str(getattr(exc, "orig", None) or exc).splitlines()[0]
        print(f"intspace serve: storage error: {reason}", file=sys.stderr, flush=True)
        return 2
    app = create_app(settings)
    host = _browser_host(bind)
    print(f"Dashboard: http://{host}:{port}/", flush=True)
    if settings.viser_enabled:
        print(
            f"3D scene: http://{host}:{port}/api/v1/scene/view/ (viser listens on "
            f"127.0.0.1:{settings.viser_port} only; the API proxies it behind the sign-in)",
            flush=True,
        )
    else:
        print("3D scene (viser): disabled (INTSPACE_VISER_ENABLED=false)", flush=True)
    if token is not None:
        print(f"Admin token: {token}", flush=True)
        print("  (shown once; only its hash is stored)", flush=True)
    uvicorn.run(
        app,
        host=bind,
        port=port,
        workers=1,
        log_level=args.log_level,
        timeout_graceful_shutdown=10,
    )
    return 0


def run_worker(args: argparse.Namespace) -> int:
    """Claim and execute queued runs until SIGTERM/SIGINT, then hand the runs in progress back
    to the queue; return the exit code. A worker killed outright (SIGKILL) stops renewing its
    leases, and another worker re-queues its runs once they have expired."""
    from server.db.session import make_engine, make_session_factory
    from server.services.jobs import LeasePolicy
    from server.services.runs import RunExecutor

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s")
    log = logging.getLogger("intspace.worker")
    settings = Settings()
    try:
        policy = LeasePolicy.from_settings(settings)
    except ValueError as exc:
        print(f"intspace worker: error: {exc}", file=sys.stderr, flush=True)
        return 2
    engine = make_engine(settings.resolved_database_url, pool_size=settings.run_workers + 2)
    stop = threading.Event()
    stop_on_signals(
        stop,
        lambda signum: log.info(
            "signal %d: handing the runs in progress back to the queue", signum
        ),
    )
    executor = RunExecutor(
        make_session_factory(engine), settings.run_workers, policy, poll_s=args.poll
    )
    log.info(
        "worker %s polling %s (lease %g s, heartbeat %g s, at most %d attempts)",
        executor.owner,
        settings.masked()["database_url"],
        policy.lease_s,
        policy.heartbeat_s,
        policy.max_attempts,
    )
    while not stop.wait(0.5):
        pass
    released = executor.shutdown("interrupted: the worker stopped")
    log.info("worker %s stopped; %d run(s) handed back", executor.owner, released)
    engine.dispose()
    return 0
