"""`intspace serve`: migrate, print where everything is, run the API with uvicorn.
`intspace worker`: execute queued calibration runs from the shared database."""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading

from server.settings import Settings


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `serve` and `worker` commands."""
    serve = subparsers.add_parser("serve", help="Run the web service (API, dashboard, 3D scene).")
    serve.add_argument(
        "--host", default="127.0.0.1", help="Interface to bind (default: %(default)s)."
    )
    serve.add_argument("--port", type=int, default=8000, help="API port (default: %(default)s).")
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

    from server.app import create_app

    settings = Settings()
    print("Settings:", flush=True)
    for name, value in settings.masked().items():
        print(f"  {name} = {value}", flush=True)
    token = _prepare_database(settings)
    app = create_app(settings)
    app.state.viser_host = args.host
    host = _browser_host(args.host)
    print(f"Dashboard: http://{host}:{args.port}/", flush=True)
    if settings.viser_enabled:
        print(f"3D scene (viser): http://{host}:{settings.viser_port}/", flush=True)
    else:
        print("3D scene (viser): disabled (INTSPACE_VISER_ENABLED=false)", flush=True)
    if token is not None:
        print(f"Admin token: {token}", flush=True)
        print("  (shown once; only its hash is stored)", flush=True)
    uvicorn.run(
        app,
        host=args.host,
        port=args.port,
        workers=1,
        log_level=args.log_level,
        timeout_graceful_shutdown=10,
    )
    return 0


def run_worker(args: argparse.Namespace) -> int:
    """Claim and execute queued runs until SIGTERM/SIGINT; return the exit code."""
    from server.db.session import make_engine, make_session_factory
    from server.services.runs import claim_next_run, execute_claimed_run, interrupt_run

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s")
    log = logging.getLogger("intspace.worker")
    settings = Settings()
    engine = make_engine(settings.resolved_database_url, pool_size=2)
    factory = make_session_factory(engine)
    stop = threading.Event()
    current: list[int] = []

    def on_signal(signum: int, _frame: object) -> None:
        log.info("signal %d: stopping after marking the current run interrupted", signum)
        stop.set()
        for run_id in current:
            interrupt_run(factory, run_id, "interrupted: the worker stopped")
        sys.exit(0)

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    log.info("worker polling %s", settings.masked()["database_url"])
    try:
        while not stop.is_set():
            with factory() as session:
                run_id = claim_next_run(session)
            if run_id is None:
                stop.wait(args.poll)
                continue
            current.append(run_id)
            status = execute_claimed_run(factory, run_id)
            current.remove(run_id)
            log.info("run %d %s", run_id, status)
    finally:
        engine.dispose()
    return 0
