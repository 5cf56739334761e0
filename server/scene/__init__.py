"""The live 3D scene of the space, served by viser on its own port.

scene = SceneService("127.0.0.1", 8081)
scene.start()
scene.set_floor_plan([{"id": 1, "name": "Living room", "polygon": [[0, 0], [5, 0], [5, 4]]}])
scene.upsert_camera({"id": 3, "name": "ceiling-1", "width": 640, "height": 480,
                     "K": K, "T_world_camera": T})   # K, T may be None
scene.set_camera_image(3, frame_bgr)                 # throttled; False when dropped
scene.upsert_agent({"id": "robot", "kind": "robot", "x": 1.0, "y": 2.0, "theta": 0.3})
scene.set_track("robot", [[0.0, 0.0], [0.5, 1.0], [1.0, 2.0]])
scene.set_planned_path([[1.0, 2.5], [3.5, 1.6]])      # [] removes it
scene.set_projector({"name": "laser", "T_world_projector": T, "spot": [1.0, 2.5]})
scene.set_arm({"id": "7", "agent": "robot", "name": "arm", "dh": dh, "limits": limits,
               "tool": tool, "home": home, "T_robot_arm": T, "q": None})  # None: home
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
from server.scene._geometry import Frustum, Pose
from server.scene._landmarks import LandmarkView, NavigationGraphView, PlaceView, SemanticObjectView
from server.scene._navigation import ProjectorView
from server.scene._service import CameraView, RoomView, SceneService

__all__ = [
    "MAX_TRACK_POINTS",
    "AgentView",
    "ArmView",
    "CameraView",
    "Frustum",
    "LandmarkView",
    "NavigationGraphView",
    "PlaceView",
    "Pose",
    "ProjectorView",
    "RoomView",
    "SceneService",
    "SemanticObjectView",
]
