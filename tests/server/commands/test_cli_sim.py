"""`intspace sim`: JSON metrics of a scenario, the list, and clean failures on bad input."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from server.cli import main


def test_localization_json_keys(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sim", "run", "localization", "--seed", "3", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert {"samples", "sigma_px", "rmse_m", "crb_rmse_m"} <= set(data)
    assert set(data["rmse_m"]) == {"mono", "linear", "constrained", "ml"}
    assert data["samples"] >= 1000 and data["seed"] == 3


def test_list_names_the_scenarios(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sim", "list"]) == 0
    out = capsys.readouterr().out
    for name in ("network-calibration", "localization", "localization-images"):
        assert name in out


@pytest.mark.parametrize("text", ["cameras: [1", "name: x\nceiling_height: -1\nrooms: []\n", "{}"])
def test_bad_scene_file_exits_2_without_traceback(tmp_path: Path, text: str) -> None:
    f = tmp_path / "scene.yaml"
    f.write_text(text)
    p = subprocess.run(
        [sys.executable, "-m", "server.cli", "sim", "run", "localization", "--scene", str(f)],
        capture_output=True,
        text=True,
        check=False,
    )
    assert p.returncode == 2
    assert "Traceback" not in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1 and "error" in p.stderr


def test_negative_seed_is_one_line_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    # Refused before any scenario runs (numpy's generators take non-negative seeds only).
    assert main(["sim", "run", "localization", "--seed", "-1"]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    lines = captured.err.strip().splitlines()
    assert lines == ["intspace sim: error: --seed must be a non-negative integer; got -1"]


def test_missing_scene_file_and_unknown_scenario(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["sim", "run", "localization", "--scene", str(tmp_path / "no.yaml")]) == 2
    assert main(["sim", "run", "nope"]) == 2
    err = capsys.readouterr().err
    assert "cannot read scene file" in err and "unknown scenario" in err


def test_tracking_async_json_contract(capsys: pytest.CaptureFixture[str]) -> None:
    # Shortened, never eased: the scenario's conditions with half a minute of walking.
    assert main(["sim", "run", "tracking-async", "--seed", "5", "--minutes", "0.5", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    keys = {"minutes", "targets", "idf1", "mota", "id_switches", "max_live_targets"}
    assert keys | {"person_rmse_m"} <= set(data)
    assert data["minutes"] == 0.5 and data["targets"] == 3
    assert data["conditions"]["noise_px"] == 0.7 and data["conditions"]["miss"] == 0.05


def test_minutes_is_refused_where_a_scenario_has_no_length(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert main(["sim", "run", "localization", "--minutes", "2"]) == 2
    assert "no length" in capsys.readouterr().err
    assert main(["sim", "run", "tracking-async", "--minutes", "0"]) == 2
    assert "positive" in capsys.readouterr().err
