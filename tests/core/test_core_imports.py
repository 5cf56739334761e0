"""core/'s imports only go down: no circle among its modules, and nothing of the service.
Read from the source (every import, at the top of a module or inside a function)."""

from __future__ import annotations

from pathlib import Path

from tests.support.import_graph import circles, import_graph

CORE = Path(__file__).resolve().parents[2] / "core"


def test_the_graph_sees_imports_inside_functions():
    # The installation's calibration imports its drive inside a function (it is the costly
    # path, taken only when no calibration is shipped for the scene); a check blind to such
    # imports would pass on a circle closed there.
    graph = import_graph(CORE)
    assert "core.sim.network_registration" in graph["core.sim.installation"]


def test_core_forms_no_circle():
    assert circles(import_graph(CORE)) == []


def test_a_circle_is_found():
    # The check itself: a circle of three modules and a module outside it.
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a", "d"}, "d": set()}
    assert circles(graph) == [["a", "b", "c"]]


def test_core_imports_nothing_of_the_service():
    graph = import_graph(CORE)
    # import_graph keeps core's own modules only; the service is looked for in the source text.
    assert graph
    offenders = [
        str(p.relative_to(CORE.parent))
        for p in CORE.rglob("*.py")
        if "from server" in p.read_text() or "import server" in p.read_text()
    ]
    assert offenders == []
