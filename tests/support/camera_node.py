"""`intspace node` started as a user starts it, and the twin's camera registered as its
installation calibrated it (not the twin's true camera), as the node tests' service knows it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

from core.sim import Scene
from core.sim.installation import installed_calibration
from tests.support.service import clean_env

# `intspace node` as the tests run it: this Python's module, from the repository's root.
NODE = (sys.executable, "-m", "server.cli", "node")


def node_env(token: str) -> dict[str, str]:
    """Return the environment of a node speaking with `token`: this process's without any
    INTSPACE_ setting, then INTSPACE_TOKEN."""
    env = clean_env()
    env["INTSPACE_TOKEN"] = token
    return env


def start_node(
    repo_root: Path, *args: str, token: str, log: Path | None = None
) -> subprocess.Popen:
    """Start `python -m server.cli node *args` from `repo_root` with INTSPACE_TOKEN `token` (and
    no other INTSPACE_ setting); its stderr goes to `log` (a long run) or a pipe (read at
    exit), its stdout nowhere."""
    return subprocess.Popen(
        [*NODE, *args],
        cwd=repo_root,
        env=node_env(token),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE if log is None else log.open("w"),
        text=True,
    )


def installed_camera(scene: Scene, name: str, **fields: Any) -> dict[str, Any]:
    """Return the body of POST /cameras for `scene`'s camera `name` with the calibration its
    installation found (640 x 480), followed by `fields` (a `space_id`)."""
    cal = next(c for c in installed_calibration(scene).cameras if c.name == name)
    return {
        "name": name,
        **fields,
        "width": 640,
        "height": 480,
        "K": cal.K.tolist(),
        "dist": cal.dist.tolist(),
        "T_world_camera": cal.T_world_camera.tolist(),
    }
