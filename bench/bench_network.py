"""Benchmark: calibrating the twin's camera network by driving the robot, both target kinds.

Run from the repository root: `python -m bench.bench_network [--seeds 0 1]`. For each seed and
each target kind (the marker, `network-calibration`; the chessboard,
`network-calibration-board`) it prints the scenario's wall time and CPU time (rendering,
detection in the images, calibration; time.perf_counter and time.process_time) and every
camera's errors against the twin: focal %, centre cm, orientation degrees, reprojection RMS
pixels, and for the board kind the principal point error and the distortion error (pixels,
over the region the board covered and over the whole image). The spec's targets are focal
within 1 %, centre within 2 cm, orientation within 0.3 degrees; the marker kind's accuracy
against drive length, pixel noise and its Cramer-Rao bound is bench/bench_network_accuracy.py.
"""

from __future__ import annotations

import argparse
import time

from core.sim.scenarios import (
    NetworkCalibrationResult,
    network_calibration,
    network_calibration_board,
)

TARGETS = {"focal_pct": 1.0, "position_cm": 2.0, "rotation_deg": 0.3}


def _print(result: NetworkCalibrationResult, wall: float, cpu: float) -> None:
    drive = "" if result.drive_s is None else f", a {result.drive_s:.0f} s drive"
    print(
        f"{result.scenario} seed {result.seed}: {wall:.1f} s wall, {cpu:.1f} s CPU, "
        f"{result.poses} poses{drive}, {result.detections} detections at "
        f"{result.sigma_px:.3f} px (measured); joint RMS {result.rms_px:.3f} px; "
        f"intrinsics: {result.intrinsics_from}; distortion {result.distortion}"
    )
    board = result.target_kind == "board"
    head = (
        f"  {'camera':16s} {'focal %':>8} {'pos cm':>7} {'rot deg':>8} {'views':>6} {'rms px':>7}"
    )
    if board:
        head += f" {'pp px':>6} {'dist px':>8} {'dist full':>9}"
    print(head)
    for c in result.cameras:
        ok = (
            abs(c.focal_error_pct) < TARGETS["focal_pct"]
            and 100 * c.position_error_m < TARGETS["position_cm"]
            and c.rotation_error_deg < TARGETS["rotation_deg"]
        )
        line = (
            f"  {c.name:16s} {c.focal_error_pct:+8.3f} {100 * c.position_error_m:7.2f}"
            f" {c.rotation_error_deg:8.3f} {c.poses_seen:6d} {c.rms_px:7.3f}"
        )
        if board:
            line += (
                f" {c.principal_point_error_px:6.2f} {c.distortion_error_px:8.3f}"
                f" {c.distortion_error_full_px:9.2f}"
            )
        print(line + ("" if ok else "   (misses a target)"))
    for r in result.rejected:
        print(f"  {r.name}: not calibrated: {r.reason}")


def main() -> None:
    """Run both kinds for the seeds given on the command line and print their tables."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    args = parser.parse_args()
    for seed in args.seeds:
        for run in (network_calibration, network_calibration_board):
            t0, c0 = time.perf_counter(), time.process_time()
            result = run(seed=seed)
            _print(result, time.perf_counter() - t0, time.process_time() - c0)
            print()


if __name__ == "__main__":
    main()
