"""`intspace serve` binds where INTSPACE_HOST and INTSPACE_PORT say (so `make run` can move),
and its --host/--port win over them."""

from __future__ import annotations

import pytest

from server.cli import main


@pytest.fixture
def bound(monkeypatch: pytest.MonkeyPatch, tmp_path) -> dict:
    """Run `intspace serve` up to uvicorn, which records where it was asked to listen."""
    import uvicorn

    for name in ("DATABASE_URL", "HOST", "PORT", "ADMIN_TOKEN"):
        monkeypatch.delenv(f"INTSPACE_{name}", raising=False)
    monkeypatch.setenv("INTSPACE_DATA_DIR", str(tmp_path))
    monkeypatch.setenv("INTSPACE_VISER_ENABLED", "false")
    monkeypatch.chdir(tmp_path)  # no .env of the working tree
    seen: dict = {}
    monkeypatch.setattr(uvicorn, "run", lambda app, **kw: seen.update(kw))
    return seen


def test_host_and_port_from_the_environment(bound, monkeypatch, capsys):
    monkeypatch.setenv("INTSPACE_HOST", "0.0.0.0")
    monkeypatch.setenv("INTSPACE_PORT", "8765")
    assert main(["serve"]) == 0
    assert (bound["host"], bound["port"]) == ("0.0.0.0", 8765)
    # The address printed for a browser is a reachable one, on the port from the environment.
    assert "Dashboard: http://127.0.0.1:8765/" in capsys.readouterr().out


def test_arguments_win_over_the_environment_and_defaults_hold(bound, monkeypatch):
    assert main(["serve"]) == 0
    assert (bound["host"], bound["port"]) == ("127.0.0.1", 8000)
    monkeypatch.setenv("INTSPACE_PORT", "8765")
    assert main(["serve", "--port", "9001", "--host", "127.0.0.2"]) == 0
    assert (bound["host"], bound["port"]) == ("127.0.0.2", 9001)


def test_a_bad_port_in_the_environment_is_refused(bound, monkeypatch):
    from pydantic import ValidationError

    monkeypatch.setenv("INTSPACE_PORT", "70000")
    with pytest.raises(ValidationError, match="port"):
        main(["serve"])
