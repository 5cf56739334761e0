"""Fixtures for the browser tests: the service started as a user starts it, the system Chromium,
and a client of the viser scene that reads what the scene server actually sends."""

from __future__ import annotations

import contextlib
import json
import os
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from tests.support.service import running_service as serve_process

REPO = Path(__file__).resolve().parents[2]
ZHANG_DIR = REPO.parent / "shared" / "data" / "zhang1998"
CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
ADMIN_TOKEN = "browser-test-admin-token-5f1c2e"
STARTUP_TIMEOUT_S = 180.0


def _in_ci() -> bool:
    return os.environ.get("CI", "").strip().lower() not in ("", "0", "false", "no")


@pytest.fixture(scope="session")
def chromium_executable() -> str:
    """Return Debian's Chromium; a missing one fails in CI (CI=true) and skips elsewhere."""
    if not CHROMIUM.is_file():
        message = f"{CHROMIUM} is missing (apt-get install chromium)"
        if _in_ci():
            pytest.fail(f"{message}: the browser tests must run in CI")
        pytest.skip(message)
    return str(CHROMIUM)


@dataclass(frozen=True)
class Service:
    """A running `intspace serve`: where it listens, its admin token and its console output."""

    base_url: str
    viser_port: int | None
    token: str
    log_path: Path

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def api(self, method: str, path: str, body: Any = None) -> Any:
        """Call the API with the admin token; return the decoded JSON (None for no content)."""
        request = urllib.request.Request(
            f"{self.base_url}/api/v1{path}",
            method=method,
            data=None if body is None else json.dumps(body).encode(),
            headers={"Authorization": f"Bearer {self.token}", "Content-Type": "application/json"},
        )
        with urllib.request.urlopen(request, timeout=10) as response:
            raw = response.read()
        return json.loads(raw) if raw else None


@contextlib.contextmanager
def running_service(data_dir: Path, extra_env: dict[str, str] | None = None) -> Iterator[Service]:
    """Start `python -m server.cli serve` with its data in `data_dir` (tests/support/service.py),
    wait for /health, and stop it with Ctrl-C (SIGINT) at the end, failing if it does not stop
    gracefully."""
    with serve_process(
        data_dir,
        token=ADMIN_TOKEN,
        env=extra_env,
        args=("--host", "127.0.0.1"),
        timeout=STARTUP_TIMEOUT_S,
    ) as served:
        yield Service(served.base_url, served.viser_port, ADMIN_TOKEN, served.log_path)


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Service]:
    """Start `python -m server.cli serve` in a fresh data directory and wait for /health."""
    with running_service(tmp_path_factory.mktemp("intspace-data")) as svc:
        yield svc


@pytest.fixture(scope="module")
def start_service(tmp_path_factory: pytest.TempPathFactory):
    """Return start(extra_env) -> a context manager running `intspace serve` with those extra
    INTSPACE_* settings in a fresh data directory (a fixture, so tests need not import conftest)."""

    def start(extra_env: dict[str, str] | None = None):
        return running_service(tmp_path_factory.mktemp("intspace-data"), extra_env)

    return start


@contextlib.contextmanager
def chromium_page(chromium_executable: str, width: int, height: int) -> Iterator[Any]:
    """Yield a fresh page (in a context of its own, `page.context`) of a `width` x `height`
    window in headless Chromium; the browser closes at the end."""
    from playwright.sync_api import expect, sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(
            executable_path=chromium_executable, headless=True, args=CHROMIUM_ARGS
        )
        try:
            context = browser.new_context(viewport={"width": width, "height": height})
            page = context.new_page()
            # CI machines are slower than a desk: wait up to 15 s for what the page shows.
            expect.set_options(timeout=15_000)
            yield page
        finally:
            browser.close()


@pytest.fixture
def browser_page(chromium_executable: str) -> Iterator[Any]:
    """A fresh page in headless Chromium; JavaScript errors on the page fail the test."""
    errors: list[str] = []
    with chromium_page(chromium_executable, 1440, 900) as page:
        page.on("pageerror", lambda exc: errors.append(str(exc)))
        yield page
    assert not errors, f"JavaScript errors on the page: {errors}"


def zhang_correspondences() -> dict[str, Any]:
    """Return Zhang's five views as a correspondences document (object points in inches)."""
    import numpy as np

    if not (ZHANG_DIR / "Model.txt").is_file():
        pytest.fail(f"Zhang's calibration data is missing: expected it in {ZHANG_DIR}")
    model = np.loadtxt(ZHANG_DIR / "Model.txt").reshape(-1, 2)
    obj = np.column_stack([model, np.zeros(len(model))]).tolist()
    views = [np.loadtxt(ZHANG_DIR / f"data{i}.txt").reshape(-1, 2).tolist() for i in range(1, 6)]
    return {"image_size": [640, 480], "object_points": [obj] * len(views), "image_points": views}


# -- a minimal viser client ------------------------------------------------------------------


def _decode_window(raw: bytes) -> list[dict[str, Any]]:
    """Decode one viser websocket frame: two little-endian sizes, zstd msgpack, raw buffers."""
    import msgspec
    import zstandard

    size = int.from_bytes(raw[0:8], "little")
    compressed = int.from_bytes(raw[8:16], "little")
    inner = zstandard.ZstdDecompressor().decompress(raw[16 : 16 + compressed], max_output_size=size)
    return msgspec.msgpack.decode(inner)["messages"]


def read_scene(port: int, timeout: float = 10.0) -> dict[str, dict[str, Any]]:
    """Connect to the viser server as its web client does and return the scene it replays:
    node name -> {"type", "props", "position"?, "wxyz"?}.

    A synchronous websocket client: Playwright's sync API already runs an event loop here."""
    import viser
    from websockets.sync.client import connect

    nodes: dict[str, dict[str, Any]] = {}
    deadline = time.monotonic() + timeout
    with connect(
        f"ws://127.0.0.1:{port}",
        subprotocols=[f"viser-v{viser.__version__}"],
        max_size=None,
        open_timeout=timeout,
    ) as ws:
        while time.monotonic() < deadline:
            raw = ws.recv(timeout=max(deadline - time.monotonic(), 0.01))
            for m in _decode_window(raw):
                kind, name = m["type"], m.get("name")
                if kind == "ReplayDoneMessage":
                    return nodes
                if kind == "RemoveSceneNodeMessage":
                    for key in [k for k in nodes if k == name or k.startswith(f"{name}/")]:
                        del nodes[key]
                elif kind == "SetPositionMessage" and name in nodes:
                    nodes[name]["position"] = m["position"]
                elif kind == "SetOrientationMessage" and name in nodes:
                    nodes[name]["wxyz"] = m["wxyz"]
                elif kind == "SceneNodeUpdateMessage" and name in nodes:
                    nodes[name]["props"].update(m["updates"])  # e.g. a new frustum image
                elif name is not None and "props" in m:
                    nodes[name] = {"type": kind, "props": m["props"]}
    raise TimeoutError(f"the viser server on port {port} sent no complete scene in {timeout} s")


def assert_scene_frame_is_proxied(frame: Any, base_url: str) -> None:
    """The scene iframe shows the proxied viser page and its client connects through the proxy.

    Once loaded, viser's client writes the WebSocket server it derived from the page's path
    into the address (`?websocket=ws://host/api/v1/scene/view`); wait for that, then read it."""
    page = f"{base_url}/api/v1/scene/view/"
    relay = "ws://" + base_url.split("://", 1)[1] + "/api/v1/scene/view"
    expected = f"{page}?websocket={relay}"
    frame.wait_for_url(lambda url: url != page, timeout=10_000)
    assert frame.url == expected


@pytest.fixture
def scene_reader():
    """Return read_scene(port, timeout) (a fixture, so tests need not import conftest)."""
    return read_scene


@pytest.fixture
def zhang_document() -> dict[str, Any]:
    """Return Zhang's correspondences as a request-shaped document."""
    return zhang_correspondences()


@pytest.fixture
def zhang_json(tmp_path: Path) -> Path:
    """Write Zhang's correspondences to a JSON file, as a user would pick it, and return it."""
    path = tmp_path / "zhang1998-correspondences.json"
    path.write_text(json.dumps(zhang_correspondences()))
    return path


# A pinhole camera without distortion, for synthetic chessboard photos (pixels).
PHOTO_K = ((600.0, 0.0, 320.0), (0.0, 600.0, 240.0), (0.0, 0.0, 1.0))
PHOTO_SIZE = (640, 480)


@pytest.fixture
def chessboard_photos(tmp_path: Path) -> list[Path]:
    """Render six photos of a 9x6-inner-corner chessboard (25 mm squares) seen by PHOTO_K from
    0.55 m under different tilts: the exact homography K [r1 r2 t] warps a drawn board."""
    import cv2
    import numpy as np

    cols, rows, square, px = 9, 6, 0.025, 60  # px: texture pixels per square
    board = np.full(((rows + 3) * px, (cols + 3) * px), 255, np.uint8)  # one white square margin
    for j in range(rows + 1):
        for i in range(cols + 1):
            if (i + j) % 2 == 0:
                board[(j + 1) * px : (j + 2) * px, (i + 1) * px : (i + 2) * px] = 0
    to_metres = np.diag([square / px, square / px, 1.0])
    centre = np.array([board.shape[1] / 2, board.shape[0] / 2, 0.0]) * square / px
    # Rendered 4x larger and averaged down, so edges are anti-aliased as a lens and sensor do; a
    # low-resolution pixel i covers high-resolution pixels 4i .. 4i + 3, centred on 4i + 1.5.
    up = 4
    K = np.diag([up, up, 1.0]) @ np.array(PHOTO_K)
    K[:2, 2] += (up - 1) / 2
    big = (PHOTO_SIZE[0] * up, PHOTO_SIZE[1] * up)
    paths = []
    tilts = [(0.35, -0.25, 0.05), (-0.3, 0.3, -0.1), (0.2, 0.35, 0.2), (-0.35, -0.2, 0.0)]
    tilts += [(0.1, -0.4, -0.15), (0.4, 0.1, 0.1)]
    for k, rvec in enumerate(tilts):
        R, _ = cv2.Rodrigues(np.array(rvec))
        t = np.array([0.0, 0.0, 0.55]) - R @ centre
        H = K @ np.column_stack([R[:, 0], R[:, 1], t]) @ to_metres
        photo = cv2.warpPerspective(board, H, big, flags=cv2.INTER_LINEAR, borderValue=200)
        photo = cv2.resize(photo, PHOTO_SIZE, interpolation=cv2.INTER_AREA)
        path = tmp_path / f"board-{k + 1}.png"
        cv2.imwrite(str(path), photo)
        paths.append(path)
    return paths
