"""Service health and the address of the live 3D scene."""

from __future__ import annotations

from fastapi import APIRouter, Request

from server.api.deps import SessionDep, SettingsDep
from server.db.migrate import current_revision
from server.schemas.system import Health, SceneLink

router = APIRouter(tags=["system"])


@router.get("/health", response_model=Health)
def health(request: Request, session: SessionDep, settings: SettingsDep) -> Health:
    """Return liveness, version and the database backend (no token needed)."""
    return Health(
        status="ok",
        version=request.app.version,
        database=settings.database_backend,
        schema_revision=current_revision(session.connection()),
        public_reads=settings.public_reads,
        simulation=settings.simulation,
        scene=request.app.state.scene_sync.scene is not None,
    )


@router.get("/scene", response_model=SceneLink)
def scene_link(request: Request, settings: SettingsDep) -> SceneLink:
    """Return the viser scene's URL on the host the caller used (for the dashboard's iframe)."""
    host = request.url.hostname or "127.0.0.1"
    if ":" in host:
        host = f"[{host}]"
    return SceneLink(viser_url=f"http://{host}:{request.app.state.viser_port}/")
