"""Service health, the address of the live 3D scene, and the API's documentation page."""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter, HTTPException, Request, status
from fastapi.responses import FileResponse, RedirectResponse

import server
from server.api._crud import get_or_404
from server.api.deps import EngineDep, SceneDep, SessionDep, SettingsDep, WriteAccess
from server.api.errors import PROBLEM_RESPONSES
from server.db.migrate import current_revision
from server.db.models import Space
from server.db.session import storage_problem
from server.schemas.system import Health, SceneLink, SceneSpace

router = APIRouter(tags=["system"])

# Swagger UI's page: its script and style ship with the package (web/vendor/swagger-ui), so the
# documentation works offline and under the dashboard's Content-Security-Policy.
DOCS_PAGE = Path(server.__file__).resolve().parent.parent / "web" / "docs.html"
SCENE_VIEW_PATH = "/api/v1/scene/view/"


@router.get("/health", response_model=Health)
def health(
    request: Request, session: SessionDep, settings: SettingsDep, engine: EngineDep, scene: SceneDep
) -> Health:
    """Return liveness, version and the database backend (no token needed); `status` is
    "failing" with the reason in `storage` when the database's storage is known to fail."""
    problem = storage_problem(engine)
    return Health(
        status="ok" if problem is None else "failing",
        storage=problem or "ok",
        version=request.app.version,
        database=settings.database_backend,
        schema_revision=current_revision(session.connection()),
        public_reads=settings.public_reads,
        simulation=settings.simulation,
        scene=scene.scene is not None,
    )


@router.get("/scene", response_model=SceneLink)
def scene_link(request: Request, scene: SceneDep) -> SceneLink:
    """Return the address of the live 3D scene on the host and port the caller used (the
    service proxies the viser viewer, which listens on loopback only, under /api/v1/scene/view/,
    behind the same credentials as the API) and the space it shows."""
    return SceneLink(
        viser_url=str(request.base_url).rstrip("/") + SCENE_VIEW_PATH,
        space_id=scene.space_id if scene.scene is not None else None,
    )


@router.put(
    "/scene",
    response_model=SceneLink,
    dependencies=[WriteAccess],
    responses=PROBLEM_RESPONSES,
)
def show_space(
    body: SceneSpace, request: Request, session: SessionDep, scene: SceneDep
) -> SceneLink:
    """Show another space in the live 3D scene (for every viewer): its floor plan, cameras,
    robot, landmarks and maps, and no other space's. 404: no such space; 409: the scene does
    not run in this process."""
    get_or_404(session, Space, body.space_id, "space")
    if scene.scene is None:
        raise HTTPException(
            status.HTTP_409_CONFLICT,
            detail="the 3D scene does not run in this process (INTSPACE_VISER_ENABLED)",
        )
    before = scene.space_id
    scene.show(session, body.space_id)
    if body.space_id != before:
        # The robot, the people and their tracks belong to the space shown before: they leave
        # with its cameras, now, not at the twin's next frame (seconds away on a busy machine).
        scene.scene.clear_agents()
    return scene_link(request, scene)


@router.get("/docs", include_in_schema=False)
def api_docs() -> FileResponse:
    """Return the interactive API documentation (Swagger UI, served from the package)."""
    if not DOCS_PAGE.is_file():
        raise HTTPException(status.HTTP_404_NOT_FOUND, "the documentation page is not installed")
    return FileResponse(DOCS_PAGE, media_type="text/html", headers={"Cache-Control": "no-cache"})


def docs_redirect() -> RedirectResponse:
    """Send /docs to the API documentation under /api/v1/docs."""
    return RedirectResponse("/api/v1/docs", status_code=status.HTTP_308_PERMANENT_REDIRECT)
