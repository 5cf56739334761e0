"""`intspace serve` started as a user starts it, for the tests and the benchmarks.

`python -m server.cli serve --port N` runs in a subprocess from the repository's root, with the
environment it is given (this process's own without any INTSPACE_ setting, then the data
folder, the admin token and the caller's settings); its output goes to a log file. Starting
waits until `GET /api/v1/health` answers 200; stopping is Ctrl-C (SIGINT), then a kill when it
does not stop. When the service exits during start-up, does not answer, or does not stop, a
`ServiceError` says so with its log.

    with running_service(tmp_path, token=TOKEN, env=WITHOUT_TWIN) as service:
        httpx.get(f"{service.api}/cameras", headers=service.headers)
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import httpx

from tests.support.ports import free_port

REPO_ROOT = Path(__file__).resolve().parents[2]
# Neither the twin nor the 3D scene: a service that only stores and tracks what it is sent.
WITHOUT_TWIN = {"INTSPACE_SIMULATION": "false", "INTSPACE_VISER_ENABLED": "false"}
# What pydantic reads as false in a boolean setting.
FALSE_WORDS = ("0", "off", "f", "false", "n", "no")


class ServiceError(RuntimeError):
    """The service exited during start-up, did not answer, or did not stop; the message holds
    its log."""


def clean_env() -> dict[str, str]:
    """Return this process's environment without any INTSPACE_ setting: a command started
    with it reads only the settings it is given."""
    return {k: v for k, v in os.environ.items() if not k.startswith("INTSPACE_")}


class Service:
    """A started `intspace serve`: its process, its data folder, where it listens, its admin
    token and its log."""

    def __init__(
        self,
        process: subprocess.Popen[bytes],
        data_dir: Path,
        port: int,
        viser_port: int | None,
        token: str | None,
        log_path: Path,
    ) -> None:
        self.process = process
        self.data_dir = data_dir
        self.port = port
        self.viser_port = viser_port
        self.token = token
        self.log_path = log_path
        self.base_url = f"http://127.0.0.1:{port}"
        self.api = f"{self.base_url}/api/v1"

    @property
    def headers(self) -> dict[str, str]:
        """Return the headers authenticating as the service's admin (none without a token)."""
        return {"Authorization": f"Bearer {self.token}"} if self.token else {}

    def log(self) -> str:
        """Return what the service has written so far (stdout and stderr)."""
        try:
            return self.log_path.read_text(errors="replace")
        except FileNotFoundError:
            return f"({self.log_path} no longer exists)"

    def lines(self) -> list[str]:
        """Return the log's lines so far."""
        return self.log().splitlines()

    def line(self, prefix: str) -> str | None:
        """Return the log's first line starting with `prefix`, or None."""
        return next((line for line in self.lines() if line.startswith(prefix)), None)

    def _failed(self, what: str) -> ServiceError:
        return ServiceError(f"intspace serve on port {self.port} {what}; its log:\n{self.log()}")

    def wait_healthy(self, timeout: float = 120.0) -> dict[str, Any]:
        """Return the first 200 answer of GET /api/v1/health (its JSON); raise ServiceError when
        the process exits first or nothing answers within `timeout` seconds."""
        deadline = time.monotonic() + timeout
        while True:
            if self.process.poll() is not None:
                raise self._failed(f"exited with {self.process.returncode} during start-up")
            with contextlib.suppress(httpx.TransportError):
                response = httpx.get(f"{self.api}/health", headers=self.headers, timeout=2)
                if response.status_code == 200:
                    return response.json()
            if time.monotonic() > deadline:
                raise self._failed(f"did not answer GET /api/v1/health within {timeout:g} s")
            time.sleep(0.1)

    def stop(self, timeout: float = 20.0) -> int:
        """Stop the service with Ctrl-C (SIGINT) and return its exit code (its code already when
        it has exited); kill it and raise ServiceError when it does not stop within `timeout`."""
        if self.process.poll() is not None:
            return self.process.returncode
        self.process.send_signal(signal.SIGINT)
        try:
            return self.process.wait(timeout)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait(10)
            raise self._failed(f"did not stop within {timeout:g} s of SIGINT (killed)") from None

    def kill(self) -> int:
        """Kill the service (SIGKILL), as a power cut or the OOM killer would; return its exit
        code."""
        self.process.send_signal(signal.SIGKILL)
        return self.process.wait(10)


def start_service(
    data_dir: Path,
    *,
    token: str | None = None,
    env: Mapping[str, str] | None = None,
    args: Sequence[str] = (),
    log_path: Path | None = None,
    wait: bool = True,
    timeout: float = 120.0,
) -> Service:
    """Start `python -m server.cli serve --port N` on a free port with its data in `data_dir`
    and return it, healthy unless `wait` is False.

    The environment is this process's without INTSPACE_ settings, then INTSPACE_DATA_DIR,
    INTSPACE_ADMIN_TOKEN (with `token`), INTSPACE_VISER_PORT (a free port, so services started
    side by side do not collide), PYTHONUNBUFFERED (the log is written as it happens), then
    `env`. `args` follow `--port N` on the command line. The log goes to `log_path`
    (default `<data_dir>/serve.log`). The process is killed when start-up fails."""
    port = free_port()
    environ = clean_env()
    environ.update(
        INTSPACE_DATA_DIR=str(data_dir),
        INTSPACE_VISER_PORT=str(free_port()),
        PYTHONUNBUFFERED="1",
    )
    if token is not None:
        environ["INTSPACE_ADMIN_TOKEN"] = token
    environ.update(env or {})
    viser_off = environ.get("INTSPACE_VISER_ENABLED", "").lower() in FALSE_WORDS
    log_path = log_path if log_path is not None else data_dir / "serve.log"
    log_path.parent.mkdir(parents=True, exist_ok=True)
    with log_path.open("wb") as log:
        process = subprocess.Popen(
            [sys.executable, "-m", "server.cli", "serve", "--port", str(port), *args],
            cwd=REPO_ROOT,
            env=environ,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
    viser_port = None if viser_off else int(environ["INTSPACE_VISER_PORT"])
    service = Service(process, data_dir, port, viser_port, token, log_path)
    if wait:
        try:
            service.wait_healthy(timeout)
        except BaseException:
            if process.poll() is None:
                process.kill()
                process.wait(10)
            raise
    return service


@contextlib.contextmanager
def running_service(data_dir: Path, **options: Any) -> Iterator[Service]:
    """Yield a healthy service started by start_service(data_dir, **options); stop it at the
    end (ServiceError when it does not stop on Ctrl-C)."""
    service = start_service(data_dir, **options)
    try:
        yield service
    finally:
        service.stop()
