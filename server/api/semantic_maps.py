"""The maps landmarks build (spec 04): the semantic map (objects read from their marks) and the
navigation map (signposts as places, edges, shortest routes between rooms), stored per space."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Query, status
from sqlalchemy import select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from core.errors import InvalidInput
from core.landmarks import NoRoute, PayloadError
from server.api.deps import ReadAccess, SceneDep, SessionDep, WriteAccess
from server.api.errors import PROBLEM_RESPONSES, FieldProblem
from server.db.models import Camera, Space
from server.schemas.common import MAX_ID
from server.schemas.landmarks import MapObservations, MapUpdate, RouteRead
from server.services.landmarks import (
    MapObservation,
    located_observation,
    navigation_map,
    observe,
    semantic_features,
)

router = APIRouter(prefix="/maps", tags=["maps"], responses=PROBLEM_RESPONSES)
SpaceQuery = Annotated[int | None, Query(ge=1, le=MAX_ID, description="Default: the first.")]
RoomName = Annotated[str, Query(min_length=1, max_length=200)]


def _space_id(session: Session, space_id: int | None, location: str = "query") -> int:
    if space_id is None:
        first = session.scalar(select(Space.id).order_by(Space.id).limit(1))
        if first is None:
            raise HTTPException(status.HTTP_409_CONFLICT, detail="the registry has no space yet")
        return first
    if session.get(Space, space_id) is None:
        raise FieldProblem(404, "space_id", f"no space with id {space_id}", location)
    return space_id


@router.get("/semantic", dependencies=[ReadAccess])
def get_semantic_map(session: SessionDep, space_id: SpaceQuery = None) -> dict[str, Any]:
    """Return the space's semantic map: a GeoJSON-like FeatureCollection of Points (x, y on the
    floor plan, metres), one per object read from its mark: class, name, room, z, the fused
    T_world_mark, position standard deviations, last seen, reads and confidence."""
    sid = _space_id(session, space_id)
    return {"space_id": sid, **semantic_features(session, sid)}


@router.get("/navigation", dependencies=[ReadAccess])
def get_navigation_map(session: SessionDep, space_id: SpaceQuery = None) -> dict[str, Any]:
    """Return the space's navigation map: a GeoJSON-like FeatureCollection of places (Points:
    the signposts read, at the pose their payload carries) and edges (LineStrings: from the
    signposts' neighbour fields and between places of one room), with the rooms that have
    places."""
    sid = _space_id(session, space_id)
    nav = navigation_map(session, sid)
    return {"space_id": sid, "rooms": nav.rooms, **nav.to_dict()}


@router.get("/navigation/route", response_model=RouteRead, dependencies=[ReadAccess])
def get_route(
    session: SessionDep,
    from_room: Annotated[str, Query(alias="from", min_length=1, max_length=200)],
    to_room: Annotated[str, Query(alias="to", min_length=1, max_length=200)],
    space_id: SpaceQuery = None,
):
    """Return the shortest route (networkx Dijkstra over the navigation map) from a place of
    room `from` to a place of room `to`. 404 naming the room when it has no place in the map;
    422 when the two rooms are not connected by the places read so far."""
    sid = _space_id(session, space_id)
    nav = navigation_map(session, sid)
    for field, room in (("from", from_room), ("to", to_room)):
        if room not in nav.rooms:
            known = ", ".join(nav.rooms) or "none yet"
            raise FieldProblem(
                404,
                field,
                f"room {room!r} has no place in the navigation map; rooms: {known}",
                "query",
            )
    try:
        route = nav.route(from_room, to_room)
    except NoRoute as exc:
        raise FieldProblem(422, "to", str(exc), "query") from None
    graph = nav.graph
    coords = [
        [float(graph.nodes[k]["xyz"][0]), float(graph.nodes[k]["xyz"][1])] for k in route.places
    ]
    return {
        "space_id": sid,
        "from_room": from_room,
        "to_room": to_room,
        "places": list(route.places),
        "rooms": list(route.rooms),
        "length_m": route.length_m,
        "features": {
            "type": "Feature",
            "geometry": {"type": "LineString", "coordinates": coords},
            "properties": {"kind": "route", "length_m": route.length_m},
        },
    }


@router.post("/observations", response_model=MapUpdate, dependencies=[WriteAccess])
def post_map_observations(body: MapObservations, session: SessionDep, scene: SceneDep):
    """Enter read landmarks into the space's maps: object marks into the semantic map (the
    pose in the world from T_cam_mark and the camera's pose; a mark read again fuses into its
    entry, never a second one), signposts into the navigation map (a place at the pose its
    payload carries; edges rebuilt). Every observation is checked before anything is stored:
    a foreign or corrupt payload, or a camera without a pose, is a 422 naming it and nothing
    changes."""
    sid = _space_id(session, body.space_id, "body")
    parsed: list[MapObservation] = []
    for i, item in enumerate(body.observations):
        where = f"observations.{i}"
        T_world_camera = item.T_world_camera
        if item.camera_id is not None:
            camera = session.get(Camera, item.camera_id)
            if camera is None:
                raise FieldProblem(422, f"{where}.camera_id", f"no camera with id {item.camera_id}")
            if camera.T_world_camera is None:
                raise FieldProblem(
                    422,
                    f"{where}.camera_id",
                    f"camera {item.camera_id} has no pose T_world_camera; calibrate its pose or "
                    "send T_world_camera",
                )
            T_world_camera = camera.T_world_camera
        try:
            parsed.append(
                located_observation(
                    item.payload, item.T_cam_mark, item.cov, T_world_camera, item.time
                )
            )
        except PayloadError as exc:
            raise FieldProblem(
                422, f"{where}.payload", f"not a landmark payload ({exc.reason}): {exc}"
            ) from None
        except InvalidInput as exc:
            raise FieldProblem(422, where, str(exc)) from None
    try:
        update = observe(session, sid, parsed)
    except InvalidInput as exc:
        session.rollback()
        raise FieldProblem(422, "observations", str(exc)) from None
    except IntegrityError:
        session.rollback()
        raise HTTPException(
            status.HTTP_409_CONFLICT,
            detail="another request entered the same landmark at the same time; send again",
        ) from None
    scene.maps_changed(session)
    return update
