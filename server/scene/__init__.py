"""The live 3D scene of the space, served by viser on its own port.

scene = SceneService("127.0.0.1", 8081)
scene.start()
scene.set_floor_plan([RoomEntry(1, "Living room", [[0, 0], [5, 0], [5, 4]])])
scene.upsert_camera(CameraEntry(3, "ceiling-1", 640, 480, K, T))  # K, T may be None
scene.set_camera_image(3, frame_bgr)                 # throttled; False when dropped
scene.upsert_agent({"id": "robot", "kind": "robot", "x": 1.0, "y": 2.0, "theta": 0.3})
scene.set_track("robot", [[0.0, 0.0], [0.5, 1.0], [1.0, 2.0]])
scene.set_planned_path([[1.0, 2.5], [3.5, 1.6]])      # [] removes it
scene.set_projector(ProjectorEntry("laser", T, spot=[1.0, 2.5]))
scene.set_arm(ArmEntry("7", "robot", "arm", dh, limits, tool, home, T))  # q None: home
scene.set_arm_joints("7", q)                          # q (6,) rad
scene.set_arm_gripper("7", 0.115)                     # the opening between the fingers, m
scene.set_arm_box("7", T_arm_box)                     # the fetched box, in the arm's frame
scene.remove_arm_box("7")
scene.remove_arm("7")
scene.remove_agent("robot")
scene.remove_camera(3)
scene.stop()
"""

from server.scene._agents import MAX_TRACK_POINTS, AgentView
from server.scene._arm import ArmView
from server.scene._cameras import CameraView
from server.scene._entries import (
    ArmEntry,
    CameraEntry,
    LandmarkEntry,
    PlaceEntry,
    ProjectorEntry,
    RoomEntry,
    SemanticObjectEntry,
)
from server.scene._floor import RoomView
from server.scene._geometry import Frustum, Pose
from server.scene._landmarks import LandmarkView, NavigationGraphView, PlaceView, SemanticObjectView
from server.scene._navigation import ProjectorView
from server.scene._service import SceneService

__all__ = [
    "MAX_TRACK_POINTS",
    "AgentView",
    "ArmEntry",
    "ArmView",
    "CameraEntry",
    "CameraView",
    "Frustum",
    "LandmarkEntry",
    "LandmarkView",
    "NavigationGraphView",
    "PlaceEntry",
    "PlaceView",
    "Pose",
    "ProjectorEntry",
    "ProjectorView",
    "RoomEntry",
    "RoomView",
    "SceneService",
    "SemanticObjectEntry",
    "SemanticObjectView",
]
