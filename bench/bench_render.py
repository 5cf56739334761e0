"""Render throughput of the digital twin: 4 ceiling cameras at 640x480 on one core.

Target (spec 07): >= 20 frames per second in total. The static layers (floor, walls, furniture)
are rendered once per camera before timing; each timed frame draws the moving robot (with its
marker) and the walker, applies the lens remap, blur, gain and sensor noise.

Run: .venv/bin/python bench/bench_render.py [--frames N] [--threads T]
"""

from __future__ import annotations

import argparse
import time

import cv2

from core.sim.motion import Pose2D, simulate_patrol, world_state
from core.sim.render import Renderer, SensorNoise
from core.sim.scene import default_scene


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=100, help="frames per camera")
    parser.add_argument("--threads", type=int, default=1, help="OpenCV threads (1 = one core)")
    args = parser.parse_args()
    cv2.setNumThreads(args.threads)

    scene = default_scene()
    assert scene.robot is not None
    renderer = Renderer(scene)
    t0 = time.perf_counter()
    for cam in scene.cameras:
        renderer.camera(cam.name)  # builds the static layer and lens map
    setup = time.perf_counter() - t0

    dt = 1.0 / 15.0
    traj = simulate_patrol(scene.robot, args.frames * dt, dt=dt, rng=0)
    states = [
        world_state(scene, float(t), Pose2D(*p)) for t, p in zip(traj.time, traj.pose, strict=True)
    ][: args.frames]
    noise = SensorNoise(sigma=2.0, blur_sigma=0.5, gain=1.0, gain_jitter=0.02)
    t0 = time.perf_counter()
    n = 0
    for k, st in enumerate(states):
        for cam in scene.cameras:
            renderer.render(cam.name, st, rng=k, noise=noise)
            n += 1
    elapsed = time.perf_counter() - t0
    fps = n / elapsed
    print(f"static layers (4 cameras, once): {setup:.2f} s")
    print(f"{n} frames of {len(scene.cameras)} cameras at 640x480 in {elapsed:.2f} s")
    print(f"throughput: {fps:.1f} frames/s in total ({fps / len(scene.cameras):.1f} per camera)")
    print(f"target >= 20 frames/s in total: {'met' if fps >= 20 else 'NOT met'}")


if __name__ == "__main__":
    main()
