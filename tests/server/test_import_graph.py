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


def test_the_camera_node_and_its_commands_form_no_circle():
    # The node's modules once imported each other both ways (the recorder and the runner; the
    # chessboard calibration and the node command, for the service's address): a module of a
    # circle cannot be loaded, read or tested without the others.
    graph = import_graph(SERVER)
    mine = {m: e for m, e in graph.items() if m.startswith(("server.node", "server.commands"))}
    assert {"server.node.runner", "server.node.record", "server.commands.node"} <= set(mine)
    inside = {m: {t for t in e if t in mine} for m, e in mine.items()}
    assert circles(inside) == []


def test_no_service_imports_the_node():
    # The node is a program of its own (on the cameras' computers); what a service shares with
    # it (the stages' delays) lives above both, in server/.
    graph = import_graph(SERVER)
    services = [m for m in graph if m.startswith("server.services")]
    assert [(a, b) for a in services for b in graph[a] if b.startswith("server.node")] == []


def test_the_tracking_and_comms_modules_import_each_other_in_layers():
    # Each package's modules import one another only downwards, never through the package's
    # face (its __init__, which imports them).
    graph = import_graph(SERVER)
    for package in ("server.services.tracking", "server.services.comms"):
        inner = {m: e for m, e in graph.items() if m.startswith(package + ".")}
        assert len(inner) >= (8 if package.endswith("tracking") else 3)
        assert circles({m: {t for t in e if t in inner} for m, e in inner.items()}) == []
        assert [m for m, e in inner.items() if package in e] == []
