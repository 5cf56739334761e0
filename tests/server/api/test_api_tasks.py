"""Fetch tasks on the twin: run in the background, phase and result stored and read back; the
same episodes as the `grasp` scenario at the same seed, within spec 05's grasp bounds; an arm's
applied hand-eye transform used (a wrong one shows where the episodes fail); bad input refused
by name."""

from __future__ import annotations

from datetime import timedelta

import numpy as np
import pytest

from core.landmarks import ObjectMark, decode_payload, encode_payload
from core.manipulation import default_manipulator
from core.sim import Renderer
from core.sim.fetch import GraspEpisode, grasp_episode, prepare_fetch
from core.sim.gripper import GRIPPER_OPEN
from core.sim.render.landmarks import scene_landmarks
from core.sim.scenarios.manipulation import grasp
from core.sim.scene import default_scene
from server.db.base import utcnow
from server.db.models import Task
from server.services.jobs import LeasePolicy
from server.services.manipulation import PHASES, episode_phases
from tests.support.waiting import wait_for_task


def _arm(client, admin, **fields) -> dict:
    robot = client.post("/api/v1/robots", json={"name": "fetcher"}, headers=admin).json()
    response = client.post(
        "/api/v1/arms", json={"robot_id": robot["id"], "name": "arm", **fields}, headers=admin
    )
    assert response.status_code == 201, response.text
    return response.json()


def _wait(client, admin, task_id: int, stalled_after_s: float = 180.0) -> dict:
    """Return the task once it ends, with the phases seen while it ran; fail when its phase
    and progress stay the same for `stalled_after_s` seconds (never at a total deadline). A
    fetch reports once per rendered episode (~5 s of CPU; over 60 s on a loaded machine)."""
    phases = set()

    def read() -> dict:
        task = client.get(f"/api/v1/tasks/{task_id}", headers=admin).json()
        phases.add(task["phase"])
        return task

    task = wait_for_task(read, stalled_after_s=stalled_after_s)
    task["seen_phases"] = phases
    return task


# The episodes render every image (seconds each) and do the same on either database; the
# tasks' storage on PostgreSQL is exercised by the other tests of this module.
@pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)
def test_fetch_on_the_twin(paused_twin_client, admin):
    client = paused_twin_client
    arm = _arm(client, admin)
    # One episode: each renders some 50 eye-in-hand images (the scenario's test runs more).
    body = {"kind": "fetch", "arm_id": arm["id"], "episodes": 1, "seed": 0}
    response = client.post("/api/v1/tasks", json=body, headers=admin)
    assert response.status_code == 202, response.text
    assert response.json()["status"] in ("queued", "running")
    task = _wait(client, admin, response.json()["id"])
    assert task["status"] == "succeeded", task["error"]
    assert task["phase"] == "done" and task["progress"] == 1.0
    # While it ran, the task showed what it was doing: the calibration, then the phase each
    # episode was in, as the controller entered it.
    live = {f"episode 1 of 1: {p}" for p in PHASES}
    assert task["seen_phases"] <= live | {
        "queued",
        "calibrating the eye-in-hand camera",
        "teaching the mark",
        "done",
    }
    assert task["seen_phases"] & live
    result = task["result"]
    # Without an applied hand-eye transform the task calibrates first, then runs the episodes
    # from one generator in the scenario's order: the scenario's own episodes, number for
    # number.
    assert result["hand_eye"]["source"] == "calibrated"
    reference = grasp(seed=0, episodes=1)
    assert result["hand_eye"]["translation_error_mm"] == pytest.approx(
        reference.hand_eye_translation_error_mm, rel=1e-9
    )
    for mine, theirs in zip(result["per_episode"], reference.per_episode, strict=True):
        assert mine["success"] == theirs.success
        assert mine["position_error_mm"] == pytest.approx(theirs.position_error_mm, rel=1e-9)
    # Spec 05: a fetch ends with the end effector within 5 mm and 2 deg of the true grasp
    # pose (errors measured against the twin's box).
    assert result["successes"] == 1 and result["success_rate"] == 1.0
    for episode in result["per_episode"]:
        assert episode["position_error_mm"] < 5.0 and episode["rotation_error_deg"] < 2.0
        # The gripper closed on the 115 mm box (wider only when the box sits turned in it);
        # every image the controller used was rendered and searched.
        assert 115.0 <= episode["gripper_opening_mm"] < 117.0
        assert episode["frames"] > 5
        assert [p["name"] for p in episode["phases"]] == [
            "approach",
            "switch",
            "look then move",
            "grasp",
            "lift and carry",
        ]
        assert all(p["ok"] for p in episode["phases"])
    assert result["position_error_m"] == pytest.approx(
        np.median([e["position_error_mm"] for e in result["per_episode"]]) / 1e3
    )
    listing = client.get(f"/api/v1/tasks?arm_id={arm['id']}", headers=admin).json()
    assert [t["id"] for t in listing["items"]] == [task["id"]]

    # The arm's own hand-eye transform is used once it has one: one typed in 30 mm off the
    # twin's true camera mount shows where the episodes fail.
    X = default_manipulator().T_ee_camera.copy()
    X[0, 3] += 0.03
    patched = client.patch(
        f"/api/v1/arms/{arm['id']}", json={"T_ee_camera": X.tolist()}, headers=admin
    )
    assert patched.status_code == 200, patched.text
    body = {"kind": "fetch", "arm_id": arm["id"], "episodes": 1, "seed": 5}
    task = _wait(client, admin, client.post("/api/v1/tasks", json=body, headers=admin).json()["id"])
    assert task["status"] == "succeeded", task["error"]
    result = task["result"]
    assert result["hand_eye"]["source"] == "arm"
    assert result["hand_eye"]["translation_error_mm"] == pytest.approx(30.0, abs=1e-6)
    # The look-then-move servo reaches the taught view through X: the gripper lands about
    # the transform's 30 mm off, so every episode fails at the grasp.
    assert result["successes"] == 0
    assert result["failures"] == {"final pose error above 5 mm / 2 deg": 1}
    for episode in result["per_episode"]:
        assert 25.0 < episode["position_error_mm"] < 35.0
        assert episode["phases"][-1] == {"name": "grasp", "ok": False}
        assert all(p["ok"] for p in episode["phases"][:-1])
    # On the twin, an unknown arm or one the twin cannot place are refused by name.
    response = client.post("/api/v1/tasks", json={"kind": "fetch", "arm_id": 99}, headers=admin)
    assert response.status_code == 422
    assert response.json()["errors"][0]["field"] == "arm_id"
    odd = client.post(
        "/api/v1/arms",
        json={
            "robot_id": arm["robot_id"],
            "name": "odd",
            "dh": {"a": [0.1] * 6, "d": [0.1] * 6, "alpha": [0.3] * 6},
        },
        headers=admin,
    ).json()
    response = client.post(
        "/api/v1/tasks", json={"kind": "fetch", "arm_id": odd["id"]}, headers=admin
    )
    assert response.status_code == 422 and "Puma" in response.json()["errors"][0]["reason"]


def test_fetch_refuses_bad_input(client, admin):
    arm = _arm(client, admin)
    # Without the twin there is nothing to fetch in.
    response = client.post(
        "/api/v1/tasks", json={"kind": "fetch", "arm_id": arm["id"]}, headers=admin
    )
    assert response.status_code == 409 and "INTSPACE_SIMULATION" in response.json()["detail"]
    for body in (
        {"kind": "fetch", "arm_id": arm["id"], "episodes": 0},
        {"kind": "fetch", "arm_id": arm["id"], "episodes": 101},
        {"kind": "dance", "arm_id": arm["id"]},
        {"kind": "fetch"},
    ):
        response = client.post("/api/v1/tasks", json=body, headers=admin)
        assert response.status_code == 422, body
    assert client.get("/api/v1/tasks/77", headers=admin).status_code == 404


def test_every_failure_of_an_episode_names_its_phase():
    # The phases a stored episode shows are the ones the controller entered: a failed
    # episode's phase (core.sim's grasp episode records it) is the last, failed; the earlier
    # ones passed; a success passed them all.
    for k, phase in enumerate(PHASES):
        episode = GraspEpisode(False, 1.0, 1.0, 1.0, 0.5, 1, 1, "any reason", phase)
        phases = episode_phases(episode)
        assert [p.name for p in phases] == list(PHASES[: k + 1])
        assert phases[-1].ok is False and all(p.ok for p in phases[:-1])
    done = episode_phases(GraspEpisode(True, 1.0, 1.0, 1.0, 0.5, 1, 4, "", "lift and carry"))
    assert [(p.name, p.ok) for p in done] == [(p, True) for p in PHASES]


def test_a_task_whose_process_stopped_reads_interrupted(client, admin):
    # A task left running by a process that died (no heartbeat for an hour) is not shown as
    # running forever: reading tasks marks it interrupted, with the reason.
    with client.app.state.runtime.session_factory() as session:
        task = Task(
            kind="fetch",
            status="running",
            inputs={},
            phase="episode 2 of 5",
            # Its lease (60 s) ran out an hour after its process's last heartbeat.
            **LeasePolicy(lease_s=60.0).lease("gone:1:0", utcnow() - timedelta(hours=1)),
        )
        session.add(task)
        session.commit()
        task_id = task.id
    task = client.get(f"/api/v1/tasks/{task_id}", headers=admin).json()
    assert task["status"] == "interrupted" and "stopped" in task["error"]
    assert task["finished_at"] is not None


def test_survey_on_the_twin_fills_the_maps(paused_twin_client, admin):
    client = paused_twin_client
    # 25 simulated seconds of the survey: the sweep at the start (the living room's west
    # side), then PBVS reads of the thermostat (at about 11 s) and the kitchen-door signpost
    # (about 21 s): one entry in each map.
    body = {"kind": "survey", "duration_s": 25, "seed": 1}
    response = client.post("/api/v1/tasks", json=body, headers=admin)
    assert response.status_code == 202, response.text
    task = _wait(client, admin, response.json()["id"], stalled_after_s=240)
    assert task["status"] == "succeeded", task["error"]
    assert task["arm_id"] is None and task["progress"] == 1.0
    # While it ran it showed where it was: the first stop's sweep and reads.
    assert "stop 1 of 15: sweeping the head" in task["seen_phases"]
    result = task["result"]
    assert result["completed"] is False and 25 <= result["time_s"] < 32
    assert not result["collided"]
    entries = {(e["map"], e["mark_id"]): e for e in result["entries"]}
    assert {"semantic", "navigation"} <= {m for m, _ in entries}
    # What the task read is in the space's maps, served over REST.
    semantic = client.get("/api/v1/maps/semantic", headers=admin).json()
    mapped = {f["properties"]["id"]: f for f in semantic["features"]}
    assert set(mapped) == {k for m, k in entries if m == "semantic"}
    places = client.get("/api/v1/maps/navigation", headers=admin).json()
    ids = {f["properties"]["id"] for f in places["features"] if f["properties"]["kind"] == "place"}
    assert ids == {k for m, k in entries if m == "navigation"}
    # Each object sits where the twin put its mark: read from under 1 m (pose error about 1 %
    # of distance) after a few metres of odometry from the known start (slip 1 cm per
    # sqrt(m)): within 5 cm.
    truth = {
        decode_payload(m.text).id: m.T_world_mark[:3, 3] for m in scene_landmarks(default_scene())
    }
    for mark_id, feature in mapped.items():
        x, y = feature["geometry"]["coordinates"]
        z = feature["properties"]["z"]
        assert np.linalg.norm(np.array([x, y, z]) - truth[mark_id]) < 0.05, mark_id
    assert result["truth"]["false_entries"] == 0 and result["truth"]["duplicate_entries"] == 0
    # Bad input is refused by name; without the twin (the `client` fixture) it is a 409.
    for bad in ({"kind": "survey", "duration_s": 0}, {"kind": "survey", "seed": -1}):
        response = client.post("/api/v1/tasks", json=bad, headers=admin)
        assert response.status_code == 422, bad


def _assert_scene_showed_the_box(scene, arm: dict, reported: list) -> None:
    """The 3D scene drew the fetched box where the episode had it when the arm was at the
    joints drawn with it, and took it away when the task ended."""
    log = scene.log
    sent = [i for i, (name, _) in enumerate(log) if name == "set_arm_box"]
    assert sent, "the box was never drawn"
    closed = [i for i, (name, _) in enumerate(log) if name == "set_arm_gripper"][1]
    mount = np.asarray(arm["T_robot_arm"])
    for i in sent:
        (arm_id, T) = log[i][1]
        name, (_, q) = log[i - 1]
        assert arm_id == str(arm["id"]) and name == "set_arm_joints"
        # The box the episode had when its arm was at q: the last one reported before them.
        steps = [
            k for k, (kind, v) in enumerate(reported) if kind == "joints" and np.array_equal(v, q)
        ]
        boxes = [next(v for kind, v in reversed(reported[:k]) if kind == "box") for k in steps]
        assert any(np.array_equal(T, b) for b in boxes), "a box pose the episode never had"
        if i < closed:
            # On the table, in the robot's frame (T_robot_arm @ T_arm_box): its top at the
            # map's 0.85 m, face up.
            T_robot_box = mount @ np.asarray(T)
            assert T_robot_box[2, 3] == pytest.approx(0.85, abs=1e-9)
            np.testing.assert_allclose(T_robot_box[:3, 2], [0.0, 0.0, 1.0], atol=1e-9)
    # The task ended: the box went, after every pose sent, then the arm was drawn at home.
    names = [name for name, _ in log]
    gone = len(names) - 1 - names[::-1].index("remove_arm_box")
    assert log[gone][1] == (str(arm["id"]),) and gone > sent[-1]
    assert names[gone + 1 :] == ["set_arm"]


class _SceneRecorder:
    """Stands in for the live 3D scene: records the calls the service makes, by method
    (`calls`) and in order (`log`: (method, args))."""

    def __init__(self) -> None:
        self.calls: dict[str, list[tuple]] = {}
        self.log: list[tuple[str, tuple]] = []

    def __getattr__(self, name):
        def record(*args):
            self.calls.setdefault(name, []).append(args)
            self.log.append((name, args))

        return record


def _yawed(x: float, y: float, z: float, yaw: float, tilt: float = 0.0) -> np.ndarray:
    """Return a mark pose: at (x, y, z), turned by yaw about +Z, then tilted about its x."""
    c, s, ct, st = np.cos(yaw), np.sin(yaw), np.cos(tilt), np.sin(tilt)
    T = np.eye(4)
    T[:3, :3] = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ np.array(
        [[1, 0, 0], [0, ct, -st], [0, st, ct]]
    )
    T[:3, 3] = [x, y, z]
    return T


def _read_mark(client, admin, space: int, mark_id: int, name: str, T: np.ndarray) -> None:
    """Enter an object mark into the space's semantic map as read at world pose T."""
    payload = encode_payload(ObjectMark(mark_id, "box", name, "kitchen", (0.1, 0.1, 0.1)))
    observation = {
        "payload": payload,
        "T_cam_mark": T.tolist(),
        "cov": (1e-6 * np.eye(6)).tolist(),
        "T_world_camera": np.eye(4).tolist(),  # the pose is read in the world frame
    }
    body = {"space_id": space, "observations": [observation]}
    response = client.post("/api/v1/maps/observations", json=body, headers=admin)
    assert response.status_code == 200, response.text


@pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)
def test_fetch_an_object_of_the_semantic_map(paused_twin_client, admin):
    client = paused_twin_client
    arm = _arm(client, admin)
    space = client.app.state.runtime.twin.space_id
    # A tea box on the dining table, its mark on its top (table 0.75 m + box 0.10 m), as the
    # semantic map holds it; a mark on a cupboard door (vertical); a box in the bedroom.
    table = _yawed(6.25, 1.66, 0.85, 0.6)
    _read_mark(client, admin, space, 41, "tea box", table)
    _read_mark(client, admin, space, 42, "cupboard", _yawed(6.4, 0.63, 0.97, 0.0, np.pi / 2))
    _read_mark(client, admin, space, 43, "bedside box", _yawed(6.5, 4.5, 0.85, 0.0))
    stored = client.get(f"/api/v1/maps/semantic?space_id={space}", headers=admin).json()
    held = {f["properties"]["id"]: f["properties"] for f in stored["features"]}
    assert set(held) == {41, 42, 43}

    scene = _SceneRecorder()
    client.app.state.runtime.scene_sync.scene = scene
    body = {"kind": "fetch", "arm_id": arm["id"], "object": "Tea Box", "episodes": 1, "seed": 3}
    response = client.post("/api/v1/tasks", json=body, headers=admin)
    assert response.status_code == 202, response.text
    task = _wait(client, admin, response.json()["id"])
    assert task["status"] == "succeeded", task["error"]
    # The 3D scene drew the arm on the twin's robot at home, moved its joints (within its
    # limits) while the task ran, and put it back at home at the end.
    drawn = scene.calls["set_arm"]
    assert len(drawn) == 2 and all(d.id == str(arm["id"]) for (d,) in drawn)
    assert all(d.agent == "robot" and d.q is None for (d,) in drawn)  # None: home
    moves = np.array([q for _, q in scene.calls["set_arm_joints"]])
    assert len(moves) >= 2 and moves.shape[1] == 6
    limits = np.asarray(arm["limits"])
    assert np.all((moves >= limits[:, 0]) & (moves <= limits[:, 1]))
    assert np.ptp(moves, axis=0).max() > 0.1  # it moved
    # The gripper opened at the start of the episode and closed on the box (115 mm wide).
    grips = [opening for _, opening in scene.calls["set_arm_gripper"]]
    assert grips[::2] == [GRIPPER_OPEN] and len(grips) == 2
    assert all(0.115 <= g < 0.117 for g in grips[1::2])
    # The task takes the map's pose of the object named (any case), nothing else.
    target = task["inputs"]["object"]
    assert target["id"] == 41 and target["name"] == "tea box"
    assert target["T_world_mark"] == held[41]["T_world_mark"]
    # The same episodes as the twin's grasp episode from that prior, run here from the seed
    # (the twin's box lies off the map's pose by the prior's errors; the controller finds it).
    rng = np.random.default_rng(3)
    mm = default_manipulator()
    renderer = Renderer(default_scene(), supersample=1)
    # The camera's own calibration, the hand-eye calibration and the taught image, as the
    # task's (and the grasp scenario's).
    prep = prepare_fetch(rng, mm, sigma_px=0.5, renderer=renderer)
    prior = np.asarray(held[41]["T_world_mark"])
    reported: list[tuple[str, np.ndarray]] = []  # the episode's joints and box, in order
    for mine in task["result"]["per_episode"]:
        theirs = grasp_episode(
            rng,
            mm,
            prep.X,
            intrinsics=prep.intrinsics,
            sigma_px=0.5,
            T_world_prior=prior,
            renderer=renderer,
            taught=prep.taught,
            on_joints=lambda q: reported.append(("joints", q)),
            on_box=lambda T: reported.append(("box", T)),
        )
        assert mine["success"] == theirs.success
        assert mine["position_error_mm"] == pytest.approx(theirs.position_error_mm, rel=1e-9)
    _assert_scene_showed_the_box(scene, arm, reported)
    # Spec 05's grasp bounds: within 5 mm and 2 deg of the true grasp pose, the episode.
    result = task["result"]
    assert result["successes"] == 1
    for episode in result["per_episode"]:
        assert episode["position_error_mm"] < 5.0 and episode["rotation_error_deg"] < 2.0

    # Refused by name: not in the map (404), in the map but out of the fetch's reach (409).
    def refused(ref, status: int, words: str) -> None:
        body = {"kind": "fetch", "arm_id": arm["id"], "object": ref}
        response = client.post("/api/v1/tasks", json=body, headers=admin)
        assert response.status_code == status, response.text
        (error,) = response.json()["errors"]
        assert error["field"] == "object" and words in error["reason"], error

    refused("teapot", 404, "no object 'teapot'")
    refused(99, 404, "41 (tea box)")
    refused("cupboard", 409, "faces 90 deg away from up")
    refused(43, 409, "no base pose in the kitchen corridor")
    _read_mark(client, admin, space, 44, "Tea box", _yawed(6.5, 1.62, 0.85, 0.0))
    refused("tea box", 409, "2 objects are called 'tea box' (ids 41, 44)")
