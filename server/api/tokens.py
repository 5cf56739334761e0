"""API tokens: admins create (shown once), list and revoke them. Dashboard sessions are
tokens too (kind "session"): they are not listed, and revoking a token ends its sessions."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path, status
from sqlalchemy import select

from server.api._crud import get_or_404, paginate
from server.api.deps import AdminAccess, PageDep, SessionDep, TokenCacheDep
from server.api.errors import PROBLEM_RESPONSES, FieldProblem
from server.db.models import ApiToken, Camera
from server.schemas.common import MAX_ID, Page
from server.schemas.tokens import TokenCreate, TokenCreated, TokenRead
from server.services.auth import KIND_API, create_token

router = APIRouter(
    prefix="/tokens", tags=["tokens"], responses=PROBLEM_RESPONSES, dependencies=[AdminAccess]
)


@router.post("", response_model=TokenCreated, status_code=status.HTTP_201_CREATED)
def create_api_token(body: TokenCreate, session: SessionDep):
    """Create a token; the response is the only place the token itself ever appears. An
    ingest token (a camera node's) may be bound to the cameras it speaks for."""
    for index, camera_id in enumerate(body.camera_ids or []):
        if session.get(Camera, camera_id) is None:
            raise FieldProblem(422, f"camera_ids.{index}", f"no camera with id {camera_id}")
    row, token = create_token(session, body.name, list(body.scopes), body.camera_ids)
    session.commit()
    return TokenCreated.model_validate(
        {**TokenRead.model_validate(row).model_dump(), "token": token}
    )


@router.get("", response_model=Page[TokenRead])
def list_api_tokens(session: SessionDep, page: PageDep):
    """Return a page of API tokens (names, scopes, cameras; never the tokens)."""
    stmt = select(ApiToken).where(ApiToken.kind == KIND_API).order_by(ApiToken.id)
    return paginate(session, stmt, page)


@router.delete("/{token_id}", status_code=status.HTTP_204_NO_CONTENT)
def revoke_api_token(
    token_id: Annotated[int, Path(ge=1, le=MAX_ID)], session: SessionDep, tokens: TokenCacheDep
) -> None:
    """Revoke a token: it stops working at once (in other API processes within seconds)."""
    get_or_404(session, ApiToken, token_id, "token").revoked = True
    session.commit()
    tokens.clear()
