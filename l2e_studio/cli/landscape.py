"""``l2e-studio landscape``: 1-D MI sweeps along the six axes around an extrinsic, and a 2-D sweep."""

from __future__ import annotations

import argparse
from pathlib import Path


NAME = "landscape"
HELP = "Sweep the MI along each of the six parameters (and over two of them) around an extrinsic."


def add_arguments(p: argparse.ArgumentParser) -> None:
    from . import _qa_common as common

    common.add_scene_args(p)
    p.add_argument("--at", type=Path, help="extrinsic at the centre (result file...; default: the seed)")
    p.add_argument("--span-m", type=float, default=0.05, help="+- translation span, m (default: %(default)s)")
    p.add_argument("--span-deg", type=float, default=2.0, help="+- rotation span, deg (default: %(default)s)")
    p.add_argument("--steps", type=int, default=21, help="steps per 1-D sweep (default: %(default)s)")
    p.add_argument("--pair", default="", help="two axes for a 2-D sweep, e.g. z,rx (axes: x y z rx ry rz)")
    p.add_argument("--out", type=Path, default=Path("l2e_landscape.json"), help="JSON or YAML (default: %(default)s)")


def run(args: argparse.Namespace) -> int:
    from ..calibrate import stack_scenes
    from ..io.cameras import load_seed
    from ..qa.landscape import axis_index, sweep2d, sweeps
    from . import _qa_common as common

    pair = [a for a in args.pair.split(",") if a]
    if pair and len(pair) != 2:
        from ..errors import InputError

        raise InputError(None, f"--pair takes two axes, got {args.pair!r}")
    for a in pair:
        axis_index(a)
    common.check_writable(args.out)
    ss = common.load_scenes(args)
    centre = load_seed(args.at) if args.at else ss.seed
    stack = stack_scenes(ss.scenes, ss.camera, centre, common.settings(args))
    sw = sweeps(stack, centre, args.span_m, args.span_deg, args.steps)
    data = {"centre_T_cam_lidar": centre.matrix.tolist(), "sweeps": [s.to_dict() for s in sw]}
    for s in sw:
        unit = "m" if s.axis in ("x", "y", "z") else "deg"
        print(f"{s.axis:>3}: peak at {s.peak_offset:+.4g} {unit}, half width {s.half_width():.4g} {unit}, "
              f"second peak {100 * s.secondary_ratio():.0f}% of the main one")
    if pair:
        span = lambda a: args.span_m if axis_index(a) < 3 else args.span_deg  # noqa: E731
        data["sweep2d"] = sweep2d(stack, centre, pair[0], pair[1], span(pair[0]), span(pair[1]), max(5, args.steps // 2 + 1)).to_dict()
    common.write(args.out, common.dump(data, args.out))
    print(f"landscape written to {args.out}")
    return 0
