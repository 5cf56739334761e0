"""Arms on the robots in the live scene: each link frame of the Denavit-Hartenberg chain at
the arm's joint values, the links between them, the gripper and the box it is fetching.

An arm is drawn inside its robot's agent frame (`/agents/<agent>/arm-<id>`), so it rides
along when the robot moves; the frames come from core.manipulation's forward kinematics
(`DHArm.frames`), never recomputed here. A joint update moves the eight frames and redraws
the link poly-line: a few small messages, fine at the ~10 Hz a task reports.

The box a fetch task reports (the twin's, core.sim.marked_box: BOX_SIZE with its
chessboard MARK_BOARD printed on its top) is drawn in the arm's base frame at the pose the
task gives, T_arm_box: on the table as the robot drives to it, between the fingers as it lifts.

`ArmLayer` is the part of SceneService that holds and draws arms; it uses the service's lock
(`_cond`) and viser server (`_server`).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from core.errors import IntspaceError, InvalidInput
from core.manipulation import DHArm
from core.sim.marked_box import BOX_SIZE, MARK_BOARD, T_MARK_BOARD
from server.scene._agents import agent_id
from server.scene._entries import ArmEntry
from server.scene._geometry import Pose, pose_from_transform

Array = NDArray[np.float64]

_COLOR_LINK = (71, 85, 105)
_COLOR_GRIPPER = (30, 41, 59)
# Frames drawn: the arm's base (0), the six links' (1-6, 6 = flange), the end effector (7).
FRAME_NAMES = ("base", "link1", "link2", "link3", "link4", "link5", "flange", "ee")
# Finger length when the tool puts the end effector at the flange (no length to draw from).
_MIN_FINGER = 0.04
_FINGER_THICKNESS = 0.01
# The widest opening accepted, and the palm's width (the fingers slide along it).
_MAX_OPENING = 0.3
_MAX_PALM = 0.16
_COLOR_BOX = (200, 160, 110)  # cardboard
_COLOR_PRINT = (245, 245, 245)
_COLOR_SQUARE = (20, 20, 20)
# The print's paper and its dark squares stand this far (m) proud of the box's top and of the
# paper, so the viewer's depth buffer keeps them apart from a few metres away.
_PRINT_LIFT = 0.001


def mark_squares() -> tuple[Array, NDArray[np.int64]]:
    """Return the dark squares of the box's printed chessboard as a mesh in the box's mark
    frame: vertices (4 n, 3) m, four per square, on the top (z = 0), and faces (2 n, 3).

    The print is the renderer's (core.sim.render): the board's square in row i, column j
    spans [j - 1, j] x [i - 1, i] squares in the board frame (origin at the first inner
    corner), dark when i + j is even; T_MARK_BOARD takes it to the mark frame."""
    cols, rows = MARK_BOARD.inner_corners
    s = MARK_BOARD.square_size
    ii, jj = np.meshgrid(np.arange(rows + 1), np.arange(cols + 1), indexing="ij")
    dark = (ii + jj) % 2 == 0
    low = np.stack([jj[dark] - 1, ii[dark] - 1], axis=1) * s  # (n, 2) lower corners
    quad = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]) * s
    board = (low[:, None, :] + quad[None]).reshape(-1, 2)
    board = np.concatenate([board, np.zeros((len(board), 1))], axis=1)
    vertices = board @ T_MARK_BOARD[:3, :3].T + T_MARK_BOARD[:3, 3]
    first = 4 * np.arange(len(low))[:, None, None]
    faces = (first + np.array([[0, 1, 2], [0, 2, 3]])).reshape(-1, 3)
    return vertices, faces


_SQUARES = mark_squares()


@dataclass(frozen=True)
class ArmSpec:
    """An arm as asked for: its id (scene key), the agent it is mounted on, name, kinematic
    model, mount T_agent_arm (4, 4), joint values q (6,) rad, the gripper's opening (m) and
    the box it is fetching, T_arm_box (4, 4; its mark frame in the arm's base frame), if any."""

    id: str
    agent: str
    name: str
    model: DHArm
    T_agent_arm: Array
    q: Array
    opening: float = 0.06
    box: Array | None = None

    def frames(self) -> Array:
        """Return the drawn frames T_arm_i (8, 4, 4): arm base, links 1-6, end effector."""
        return self.model.frames(self.q)


@dataclass(frozen=True)
class ArmView:
    """How one arm is drawn: its node (child of its agent's), the mount pose, the eight
    frames' poses (relative to the mount: `frames[i]` = T_arm_i of FK at `q`), the gripper's
    opening (m, between the fingers) and the pose of the box it is fetching (relative to the
    mount: T_arm_box; None when there is none)."""

    id: str
    agent: str
    name: str
    node: str
    q: tuple[float, ...]
    mount: Pose
    frames: tuple[Pose, ...]
    opening: float = 0.06
    box: Pose | None = None


def _matrix(value: Any, shape: tuple[int, ...], name: str) -> Array:
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInput(f"an arm's {name} must be numeric: {exc}") from None
    if a.shape != shape or not np.all(np.isfinite(a)):
        raise InvalidInput(f"an arm's {name} must be finite of shape {shape}, got {a.shape}")
    return a


def parse_arm(arm: ArmEntry) -> ArmSpec:
    """Return the checked arm (its q defaults to home); raise InvalidInput naming what is wrong
    (a field of the wrong shape, a pose that is not rigid, q outside the limits)."""
    ident = agent_id(arm.id)
    agent = agent_id(arm.agent)
    dh = arm.dh
    try:
        model = DHArm(
            name=arm.name or f"arm {ident}",
            a=_matrix(dh.get("a"), (6,), "dh.a"),
            d=_matrix(dh.get("d"), (6,), "dh.d"),
            alpha=_matrix(dh.get("alpha"), (6,), "dh.alpha"),
            offset=_matrix(dh.get("offset", [0.0] * 6), (6,), "dh.offset"),
            limits=_matrix(arm.limits, (6, 2), "limits"),
            tool=_matrix(arm.tool, (4, 4), "tool"),
            home=_matrix(arm.home, (6,), "home"),
        )
    except IntspaceError as exc:
        raise InvalidInput(f"arm {ident!r}: {exc}") from None
    mount = _matrix(arm.T_robot_arm, (4, 4), "T_robot_arm")
    pose_from_transform(mount, f"arm {ident!r} T_robot_arm")  # rigid, or InvalidInput
    q = model.home if arm.q is None else check_joints(model, arm.q, ident)
    return ArmSpec(ident, agent, model.name, model, mount, q)


def check_joints(model: DHArm, q: Any, ident: str) -> Array:
    """Return joint values q as a (6,) array; raise InvalidInput unless they are finite and
    within the arm's limits (1e-9 rad of slack for values that went through JSON)."""
    a = _matrix(q, (6,), "q")
    if not bool(model.within_limits(a, tol=1e-9)):
        raise InvalidInput(
            f"arm {ident!r}: joint values {np.round(a, 4).tolist()} are outside its limits "
            f"{np.round(model.limits, 4).tolist()}"
        )
    return a


class ArmLayer:
    """The arms of SceneService: thread-safe state changes, drawing on the scene's worker."""

    _cond: threading.Condition
    _server: Any
    _drawn_agents: dict[str, Any]

    def _init_arms(self) -> None:
        self._arm_specs: dict[str, ArmSpec] = {}
        # Arm ids to draw, and "agent/id" keys of arms to take off an agent.
        self._dirty_arms: set[str] = set()
        self._drawn_arms: dict[str, ArmView] = {}
        self._drawn_arm_specs: dict[str, ArmSpec] = {}  # worker thread only

    def _restart_arms(self) -> None:
        """Under _cond, when the server (re)starts: everything is to be drawn again."""
        self._dirty_arms = set(self._arm_specs)
        self._drawn_arms = {}
        self._drawn_arm_specs = {}

    def _arms_dirty(self) -> bool:
        return bool(self._dirty_arms)

    def _take_arms(self) -> tuple[set[str], dict[str, ArmSpec]]:
        """Under _cond: the arms changed since the last call, and every arm's spec."""
        dirty, self._dirty_arms = self._dirty_arms, set()
        return dirty, dict(self._arm_specs)

    # -- state changes (any thread) ----------------------------------------------------------

    def set_arm(self, arm: ArmEntry) -> None:
        """Add or redraw an arm of the registry on a robot (`arm.agent`, the robot's agent id;
        metres, radians; q defaults to home). Its links, frames and gripper are
        drawn inside the agent's frame once the agent is drawn, the gripper at its default
        opening and no box. Raises InvalidInput (nothing changes) for a malformed model, a
        mount that is not rigid, or q outside the limits."""
        spec = parse_arm(arm)
        with self._cond:
            old = self._arm_specs.get(spec.id)
            if old is not None and old.agent != spec.agent:
                self._dirty_arms.add(f"{old.agent}/{spec.id}")  # off the old robot
            self._arm_specs[spec.id] = spec
            self._dirty_arms.add(spec.id)
            self._cond.notify_all()

    def set_arm_joints(self, id: str, q: Any) -> None:
        """Move an arm's joints to q (6,) rad. Raises InvalidInput for an arm not in the scene
        or joint values outside its limits."""
        ident = agent_id(id)
        with self._cond:
            spec = self._arm_specs.get(ident)
        if spec is None:
            raise InvalidInput(f"no arm {ident!r} in the scene; add it with set_arm first")
        joints = check_joints(spec.model, q, ident)
        with self._cond:
            current = self._arm_specs.get(ident)
            if current is not None:
                self._arm_specs[ident] = replace(current, q=joints)
                self._dirty_arms.add(ident)
                self._cond.notify_all()

    def set_arm_gripper(self, id: str, opening: float) -> None:
        """Open or close an arm's gripper to `opening` metres between the fingers. Raises
        InvalidInput for an arm not in the scene or an opening not in [0, 0.3] m."""
        ident = agent_id(id)
        try:
            width = float(opening)
        except (TypeError, ValueError):
            raise InvalidInput(f"arm {ident!r}: the gripper opening must be a number") from None
        if not 0.0 <= width <= _MAX_OPENING:
            raise InvalidInput(
                f"arm {ident!r}: the gripper opening must be 0-{_MAX_OPENING} m, got {opening!r}"
            )
        self._replace_arm(ident, opening=width)

    def set_arm_box(self, id: str, T_arm_box: Any) -> None:
        """Draw the box an arm is fetching (the twin's: BOX_SIZE, MARK_BOARD printed on its
        top), or move it, to T_arm_box (4, 4): its mark frame (the top's centre, x along its
        length, z up out of it) in the arm's base frame, the frame its joints' forward
        kinematics are in. Raises InvalidInput (nothing changes) for an arm not in the scene
        or a pose that is not a finite rigid 4x4 transform."""
        ident = agent_id(id)
        pose_from_transform(T_arm_box, f"arm {ident!r}: T_arm_box")  # rigid, or InvalidInput
        self._replace_arm(ident, box=np.array(T_arm_box, dtype=np.float64))

    def _replace_arm(self, ident: str, **changes: Any) -> None:
        """Change fields of a drawn arm's spec and have it redrawn. Raises InvalidInput for an
        arm not in the scene."""
        with self._cond:
            current = self._arm_specs.get(ident)
            if current is None:
                raise InvalidInput(f"no arm {ident!r} in the scene; add it with set_arm first")
            self._arm_specs[ident] = replace(current, **changes)
            self._dirty_arms.add(ident)
            self._cond.notify_all()

    def remove_arm_box(self, id: str) -> None:
        """Take an arm's box out of the scene (nothing happens if there is none)."""
        ident = agent_id(id)
        with self._cond:
            current = self._arm_specs.get(ident)
            if current is not None and current.box is not None:
                self._arm_specs[ident] = replace(current, box=None)
                self._dirty_arms.add(ident)
                self._cond.notify_all()

    def remove_arm(self, id: str) -> None:
        """Remove an arm from the scene (nothing happens if it is not there)."""
        ident = agent_id(id)
        with self._cond:
            spec = self._arm_specs.pop(ident, None)
            if spec is not None:
                self._dirty_arms.add(f"{spec.agent}/{ident}")
                self._cond.notify_all()

    def arms(self) -> dict[str, ArmView]:
        """Return the arms as currently drawn, by id (an arm whose robot is not drawn yet is
        not: it appears with its robot)."""
        with self._cond:
            return dict(self._drawn_arms)

    # -- drawing (worker thread) -------------------------------------------------------------

    def _draw_arms(self, dirty: set[str], specs: dict[str, ArmSpec]) -> None:
        """Draw the arms changed, and those whose robot was drawn again (redrawing an agent
        removes its children); an arm whose robot is not drawn waits for it."""
        server = self._server
        if server is None:
            return
        with self._cond:
            drawn = dict(self._drawn_arms)
            agents = set(self._drawn_agents)
        with server.atomic():
            for key in sorted(k for k in dirty if "/" in k):
                agent, ident = key.split("/", 1)
                if ident not in specs or specs[ident].agent != agent:
                    server.scene.remove_by_name(f"/agents/{agent}/arm-{ident}")
                    if ident in drawn and drawn[ident].agent == agent:
                        drawn.pop(ident)
                        self._drawn_arm_specs.pop(ident, None)
            for ident, spec in sorted(specs.items()):
                node = f"/agents/{spec.agent}/arm-{ident}"
                if spec.agent not in agents:
                    drawn.pop(ident, None)
                    self._drawn_arm_specs.pop(ident, None)
                    continue
                root = server.scene.get_handle_by_name(node)
                if root is not None and ident not in dirty:
                    continue
                old = self._drawn_arm_specs.get(ident)
                joints_only = (
                    root is not None
                    and old is not None
                    and old.model is spec.model
                    and old.T_agent_arm is spec.T_agent_arm
                )
                drawn[ident] = self._draw_arm(server, spec, node, joints_only=joints_only)
                self._drawn_arm_specs[ident] = spec
        with self._cond:
            self._drawn_arms = drawn

    def _draw_arm(self, server: Any, spec: ArmSpec, node: str, *, joints_only: bool) -> ArmView:
        frames = spec.frames()
        poses = tuple(pose_from_transform(T, f"arm {spec.id} frame") for T in frames)
        mount = pose_from_transform(spec.T_agent_arm, f"arm {spec.id} T_robot_arm")
        names = [f"{node}/{name}" for name in FRAME_NAMES]
        if joints_only:
            for name, pose in zip(names, poses, strict=True):
                handle = server.scene.get_handle_by_name(name)
                handle.position = pose.position
                handle.wxyz = pose.wxyz
            self._draw_gripper(server, spec, names[-1], fingers_only=True)
            box = self._draw_box(server, spec, f"{node}/box", moved_only=True)
        else:
            server.scene.remove_by_name(node)
            server.scene.add_frame(node, wxyz=mount.wxyz, position=mount.position, show_axes=False)
            for i, (name, pose) in enumerate(zip(names, poses, strict=True)):
                server.scene.add_frame(
                    name,
                    wxyz=pose.wxyz,
                    position=pose.position,
                    show_axes=i in (0, len(names) - 1),  # the mount and the end effector
                    axes_length=0.08,
                    axes_radius=0.006,
                )
            self._draw_gripper(server, spec, names[-1])
            box = self._draw_box(server, spec, f"{node}/box")
            server.scene.add_label(
                f"{node}/label", spec.name, position=(0.0, 0.0, -0.05), font_screen_scale=0.7
            )
        # The links: straight segments between consecutive frame origins, drawn thick.
        origins = frames[:, :3, 3]
        server.scene.add_line_segments(
            f"{node}/links",
            points=np.stack([origins[:-1], origins[1:]], axis=1),
            colors=_COLOR_LINK,
            thickness=7.0,
            thickness_units="screen",
        )
        return ArmView(
            id=spec.id,
            agent=spec.agent,
            name=spec.name,
            node=node,
            q=tuple(float(v) for v in spec.q),
            mount=mount,
            frames=poses,
            opening=spec.opening,
            box=box,
        )

    @staticmethod
    def _draw_gripper(
        server: Any, spec: ArmSpec, ee_node: str, *, fingers_only: bool = False
    ) -> None:
        """Two fingers from the flange to the end effector (the fingertips' centre), `opening`
        apart along the end effector's y (the axis they close along), and the palm across the
        open fingers at the flange, in the end effector's frame. `fingers_only`: move the
        drawn fingers to the spec's opening."""
        length = max(float(np.linalg.norm(spec.model.tool[:3, 3])), _MIN_FINGER)
        half = spec.opening / 2 + _FINGER_THICKNESS / 2
        for side, y in (("left", half), ("right", -half)):
            name = f"{ee_node}/finger_{side}"
            handle = server.scene.get_handle_by_name(name) if fingers_only else None
            if handle is not None:
                handle.position = (0.0, y, -length / 2)
                continue
            server.scene.add_box(
                name,
                color=_COLOR_GRIPPER,
                dimensions=(0.015, _FINGER_THICKNESS, length),
                position=(0.0, y, -length / 2),
            )
        if not fingers_only:
            server.scene.add_box(
                f"{ee_node}/palm",
                color=_COLOR_GRIPPER,
                dimensions=(0.03, _MAX_PALM, 0.015),
                position=(0.0, 0.0, -length),
            )

    @staticmethod
    def _draw_box(
        server: Any, spec: ArmSpec, name: str, *, moved_only: bool = False
    ) -> Pose | None:
        """The box at spec.box in the arm's base frame: the body below its top, the print's
        white paper on the top and its dark squares on the paper; return its pose (None when
        the spec has no box, and a drawn one is taken away). `moved_only`: the arm was drawn
        before, so a box drawn then is only moved."""
        handle = server.scene.get_handle_by_name(name) if moved_only else None
        if spec.box is None:
            if handle is not None:
                server.scene.remove_by_name(name)
            return None
        pose = pose_from_transform(spec.box, f"arm {spec.id} T_arm_box")
        if handle is not None:
            handle.position = pose.position
            handle.wxyz = pose.wxyz
            return pose
        server.scene.add_frame(name, wxyz=pose.wxyz, position=pose.position, show_axes=False)
        height = BOX_SIZE[2]
        server.scene.add_box(
            f"{name}/body",
            color=_COLOR_BOX,
            dimensions=BOX_SIZE,
            position=(0.0, 0.0, -height / 2),
        )
        cols, rows = MARK_BOARD.inner_corners
        s = MARK_BOARD.square_size
        margin = 2 * MARK_BOARD.margin * s
        server.scene.add_box(
            f"{name}/print",
            color=_COLOR_PRINT,
            dimensions=((cols + 1) * s + margin, (rows + 1) * s + margin, _PRINT_LIFT),
            position=(0.0, 0.0, _PRINT_LIFT / 2),
            cast_shadow=False,
        )
        vertices, faces = _SQUARES
        server.scene.add_mesh_simple(
            f"{name}/squares",
            vertices=vertices,
            faces=faces,
            color=_COLOR_SQUARE,
            flat_shading=True,
            side="double",
            position=(0.0, 0.0, 2 * _PRINT_LIFT),
            cast_shadow=False,
            receive_shadow=False,
        )
        return pose
