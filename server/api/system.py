"""Service health, the address of the live 3D scene, and the API's documentation page."""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter, HTTPException, Request, status
from fastapi.responses import FileResponse, RedirectResponse

import server
from server.api.deps import SessionDep, SettingsDep
from server.db.migrate import current_revision
from server.db.session import storage_problem
from server.schemas.system import Health, SceneLink

router = APIRouter(tags=["system"])

# Swagger UI's page: its script and style ship with the package (web/vendor/swagger-ui), so the
# documentation works offline and under the dashboard's Content-Security-Policy.
DOCS_PAGE = Path(server.__file__).resolve().parent.parent / "web" / "docs.html"
SCENE_VIEW_PATH = "/api/v1/scene/view/"


@router.get("/health", response_model=Health)
def health(request: Request, session: SessionDep, settings: SettingsDep) -> Health:
    """Return liveness, version and the database backend (no token needed); `status` is
    "failing" with the reason in `storage` when the database's storage is known to fail."""
    problem = storage_problem(request.app.state.engine)
    return Health(
        status="ok" if problem is None else "failing",
        storage=problem or "ok",
        version=request.app.version,
        database=settings.database_backend,
        schema_revision=current_revision(session.connection()),
        public_reads=settings.public_reads,
        simulation=settings.simulation,
        scene=request.app.state.scene_sync.scene is not None,
    )


@router.get("/scene", response_model=SceneLink)
def scene_link(request: Request) -> SceneLink:
    """Return the address of the live 3D scene on the host and port the caller used: the
    service proxies the viser viewer (which listens on loopback only) under /api/v1/scene/view/,
    behind the same credentials as the API."""
    return SceneLink(viser_url=str(request.base_url).rstrip("/") + SCENE_VIEW_PATH)


@router.get("/docs", include_in_schema=False)
def api_docs() -> FileResponse:
    """Return the interactive API documentation (Swagger UI, served from the package)."""
    if not DOCS_PAGE.is_file():
        raise HTTPException(status.HTTP_404_NOT_FOUND, "the documentation page is not installed")
    return FileResponse(DOCS_PAGE, media_type="text/html", headers={"Cache-Control": "no-cache"})


def docs_redirect() -> RedirectResponse:
    """Send /docs to the API documentation under /api/v1/docs."""
    return RedirectResponse("/api/v1/docs", status_code=status.HTTP_308_PERMANENT_REDIRECT)
