"""The twin's cameras: real BGR images of the scene with ground truth.

How a frame is made (per camera):

1. An *ideal* pinhole image (no distortion) is rasterised on a canvas larger than the sensor, so
   that it covers everything the distorted lens sees. Planar faces (floor tiles, walls,
   furniture faces, the robot's top marker, the chessboard) are drawn by warping their textures
   with the plane's homography H = Kc [R u, R v, R o + t] (Hartley & Zisserman eq. 8.1 for a
   world plane), after clipping the face polygon against the near plane z = `near` in camera
   coordinates, so that parts behind the camera cannot wrap around into the image. Visibility
   is a z-buffer: each face's exact per-pixel depth z = d / (n . Kc^-1 (u, v, 1)) for its plane
   n . X = d. Cylinders (the robot base, people) are filled convex silhouettes.
2. The static part (floor, walls, furniture) is rendered once per camera, supersampled and box
   filtered (anti-aliased), with its depth buffer; each frame copies it and draws only what
   moves (people, robot, marker, board) against that depth.
3. Lens distortion by one cv2.remap with a map precomputed per camera: for every distorted
   output pixel, the ideal canvas pixel it sees (the undistortion of that pixel, Newton's method
   in core.geometry.camera.undistort_points).
4. Optical blur (Gaussian), exposure gain and additive Gaussian sensor noise, all seeded; a
   camera's automatic exposure stepping over time is the scenario option `ExposureChanges`.

The projector's laser spot, when a frame is asked with one, is red light added to the ideal
canvas (a Gaussian blob of the spot's size, at least a glare of ~1 px) where the camera sees it.
Cameras that move (the robot's floor camera, the eye-in-hand camera) are described by
`camera_at` at their current pose.

Pixel coordinates have their origin at the centre of the top-left pixel; colours in images are
BGR (OpenCV), in the scene (r, g, b).
"""

from core.sim.render._camera import (
    CameraModel,
    ExposureChanges,
    Frame,
    SensorNoise,
    camera_at,
    camera_model,
)
from core.sim.render._raster import _clip_near
from core.sim.render._renderer import Renderer, render, renderer_for
from core.sim.render._visibility import _disc_image_centre

__all__ = [
    "CameraModel",
    "ExposureChanges",
    "Frame",
    "Renderer",
    "SensorNoise",
    "_clip_near",
    "_disc_image_centre",
    "camera_at",
    "camera_model",
    "render",
    "renderer_for",
]
