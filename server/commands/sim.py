"""`intspace sim run SCENARIO [--seed N] [--scene FILE] [--minutes M] [--json]`, `sim list`.

Runs a named scenario of the digital twin (core.sim.scenarios) on the default home or on a
scene file (YAML or JSON, validated by core.sim.load_scene) and prints its metrics: a summary,
or one JSON object with --json. A bad scene file or scenario name gives a one-line message on
stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from core.errors import IntspaceError
from core.sim import load_scene
from core.sim.scenarios import DESCRIPTIONS, SCENARIOS, run_scenario

EXIT_USAGE = 2


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `sim` sub-command with `run` and `list`."""
    p = subparsers.add_parser("sim", help="run scenarios of the digital twin")
    sub = p.add_subparsers(dest="sim_command", metavar="ACTION")
    run = sub.add_parser("run", help="run a named scenario and print its metrics")
    run.add_argument("scenario", metavar="SCENARIO", help="scenario name (see `sim list`)")
    run.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    run.add_argument("--scene", type=Path, metavar="FILE", help="scene file, YAML or JSON")
    run.add_argument(
        "--minutes",
        type=float,
        metavar="M",
        help="simulated length of a timed scenario (tracking, tracking-async; shorter runs "
        "keep the same conditions), or how long network-calibration's drive may last "
        "(default 5)",
    )
    run.add_argument("--json", action="store_true", help="print one JSON object")
    run.set_defaults(func=_run)
    ls = sub.add_parser("list", help="list the scenarios")
    ls.set_defaults(func=_list)
    p.set_defaults(func=lambda args: (p.print_help(), EXIT_USAGE)[1])


def _fail(msg: str) -> int:
    print(f"intspace sim: error: {msg}", file=sys.stderr)
    return EXIT_USAGE


def _list(args: argparse.Namespace) -> int:
    width = max(len(name) for name in SCENARIOS) + 2
    for name in SCENARIOS:
        print(f"{name:{width}s}{DESCRIPTIONS.get(name, '')}")
    return 0


def _run(args: argparse.Namespace) -> int:
    if args.scenario not in SCENARIOS:
        return _fail(f"unknown scenario {args.scenario!r}; known: {', '.join(SCENARIOS)}")
    if args.seed < 0:
        # numpy's generators take non-negative seeds only.
        return _fail(f"--seed must be a non-negative integer; got {args.seed}")
    scene = None
    if args.scene is not None:
        try:
            text = args.scene.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            return _fail(f"cannot read scene file {args.scene}: {exc}")
        try:
            scene = load_scene(text)
        except IntspaceError as exc:
            return _fail(f"{args.scene}: {' '.join(str(exc).split())}")
    try:
        result = run_scenario(args.scenario, scene, args.seed, minutes=args.minutes)
    except IntspaceError as exc:
        return _fail(" ".join(str(exc).split()))
    data = result.to_dict()
    if args.json:
        print(json.dumps(data, indent=2))
    else:
        _print_summary(data)
    return 0


def _print_summary(data: dict[str, Any]) -> None:
    print(f"{data['scenario']} (seed {data['seed']})")
    if "idf1" in data:
        print(
            f"  {data['minutes']:g} min, {data['targets']} bodies, {data['camera_count']} cameras,"
            f" {data['frames']} frames, {data['detections']} detections"
        )
        print(
            f"  IDF1 {data['idf1']:.4f}  MOTA {data['mota']:.4f}  identity switches "
            f"{data['id_switches']}  most live targets {data['max_live_targets']}"
        )
        print(f"  person RMSE {100 * data['person_rmse_m']:.2f} cm")
        return
    if "cameras" in data:
        print(f"  target {data['target_kind']}, {data['poses']} poses, {data['detections']} det.")
        print("  camera            focal %   pos cm   rot deg   poses   rms px")
        for c in data["cameras"]:
            print(
                f"  {c['name']:16s} {c['focal_error_pct']:+7.3f} {100 * c['position_error_m']:8.2f}"
                f" {c['rotation_error_deg']:9.3f} {c['poses_seen']:7d} {c['rms_px']:8.3f}"
            )
        for r in data["rejected"]:
            print(f"  {r['name']}: not calibrated: {r['reason']}")
        return
    if "samples" not in data or "rmse_m" not in data:
        # Any other scenario: its top-level figures, one per line (lists and tables: --json).
        for key, value in data.items():
            if key in ("scenario", "seed"):
                continue
            if isinstance(value, bool | str) or value is None:
                print(f"  {key}: {value}")
            elif isinstance(value, int | float):
                print(f"  {key}: {value:.6g}")
        return
    print(f"  samples {data['samples']}, sigma {data['sigma_px']:.3f} px")
    if data.get("measured_sigma_px") is not None:
        print(f"  measured detection error (RMS per axis) {data['measured_sigma_px']:.3f} px")
    for k, v in data["rmse_m"].items():
        print(f"  {k:12s} RMSE {1000 * v:7.2f} mm")
    print(f"  Cramer-Rao   RMSE {1000 * data['crb_rmse_m']:7.2f} mm")
