"""The service's imports only go down: no circle among the services or the routers, no router
importing another, no service importing a router. Read from the source (every import, at the
top of a module or inside a function), not from what happens to be imported at run time."""

from __future__ import annotations

from pathlib import Path

from tests.support.import_graph import circles, import_graph

SERVER = Path(__file__).resolve().parents[2] / "server"
# What every router shares; the routers are the other modules of server/api.
API_SHARED = {"deps", "errors", "_crud", "limits", "server_time"}


def test_the_graph_sees_imports_inside_functions():
    # The executor once imported a service inside a function to dodge a circle; the check
    # must see such imports, or it would pass on the very circle it is for.
    graph = import_graph(SERVER)
    assert "server.services.runs" in graph["server.commands.serve"]
    assert "server.services.calibration.kinds" in graph["server.services.calibration"]


def test_services_and_routers_form_no_circle():
    graph = import_graph(SERVER)
    mine = {m: e for m, e in graph.items() if m.startswith(("server.services", "server.api"))}
    inside = {m: {t for t in e if t in mine} for m, e in mine.items()}
    assert circles(inside) == []


def test_no_router_imports_another_and_no_service_imports_a_router():
    graph = import_graph(SERVER)
    routers = {
        m for m in graph if m.startswith("server.api.") and m.rpartition(".")[2] not in API_SHARED
    }
    assert routers >= {"server.api.calibration_runs", "server.api.arms", "server.api.paths"}
    assert [(a, b) for a in routers for b in graph[a] if b in routers] == []
    services = [m for m in graph if m.startswith("server.services")]
    assert [(a, b) for a in services for b in graph[a] if b.startswith("server.api")] == []
