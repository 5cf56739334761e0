"""The digital twin: a simulated home whose cameras render real images, with ground truth.

* `load_scene(text_or_mapping)`, `default_scene()`: the validated scene (pydantic schema).
* `Renderer(scene).render(camera, state, rng=..., noise=...)` or `render(scene, ...)`: a Frame
  (BGR image and ground truth) from a ceiling camera.
* `UnicycleBase`, `Patrol`, `simulate_patrol`, `walker_positions`, `world_state`: motion of the
  robot (limits, wheel slip, odometry) and of scripted walkers on a deterministic clock.
"""

from core.sim.motion import (
    BaseState,
    Patrol,
    Pose2D,
    SimClock,
    Trajectory,
    UnicycleBase,
    WorldState,
    simulate_patrol,
    walker_positions,
    world_state,
)
from core.sim.render import (
    CameraModel,
    Frame,
    Renderer,
    SensorNoise,
    camera_model,
    render,
    renderer_for,
)
from core.sim.scene import Scene, default_scene, load_scene, scene_to_json

__all__ = [
    "BaseState",
    "CameraModel",
    "Frame",
    "Patrol",
    "Pose2D",
    "Renderer",
    "Scene",
    "SensorNoise",
    "SimClock",
    "Trajectory",
    "UnicycleBase",
    "WorldState",
    "camera_model",
    "default_scene",
    "load_scene",
    "render",
    "renderer_for",
    "scene_to_json",
    "simulate_patrol",
    "walker_positions",
    "world_state",
]
