"""``l2e-studio report``: one self-contained HTML file with everything a reviewer needs."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..errors import InputError

NAME = "report"
HELP = "Write a self-contained HTML QA report of a calibration (overlays, tables, landscapes, studies, exports)."


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--result", type=Path, required=True, help="result file (l2e-studio calibrate --out)")
    p.add_argument("--scenes", type=Path, help="scene folder (default: the result's scenes_dir, else the embedded sample)")
    p.add_argument("--camera", type=Path, help="camera file (default: the folder's)")
    p.add_argument("--truth", type=Path, help="true extrinsic, when known (default: DIR/truth.yaml if present)")
    p.add_argument("--candidate", action="append", default=[], metavar="NAME=FILE", help="more calibrations to compare")
    p.add_argument("--group", action="append", default=[], metavar="NAME=GLOB[,GLOB]", help="scene groups")
    p.add_argument("--held-out", action="append", default=[], metavar="GLOB",
                   help="held-out scenes (default: the folder's scenes the result was not calibrated on)")
    p.add_argument("--study", action="append", default=[], type=Path, help="study files to include (l2e-studio study --out)")
    p.add_argument("--pair", default="z,rx", help="two axes of the 2-D landscape (default: %(default)s)")
    p.add_argument("--steps", type=int, default=21, help="steps of the 1-D sweeps (default: %(default)s)")
    p.add_argument("--wanted-mm", type=float, help="warn when the estimated spread exceeds this (mm)")
    p.add_argument("--wanted-deg", type=float, help="warn when the estimated spread exceeds this (deg)")
    p.add_argument("--out", type=Path, default=Path("l2e_report.html"), help="HTML file (default: %(default)s)")


def run(args: argparse.Namespace) -> int:
    import numpy as np
    from ..geometry import Extrinsic
    from ..io.cameras import load_seed
    from ..qa.heldout import load_candidates, parse_groups, split_scenes
    from ..qa.report import ReportInputs, build, settings_from_result
    from . import _qa_common as common

    if args.out.suffix.lower() not in (".html", ".htm"):
        raise InputError(args.out, "the report is an HTML file: give a name ending in .html")
    common.check_writable(args.out)
    result = common.read_doc(args.result)
    if "T_cam_lidar" not in result:
        raise InputError(args.result, "not a result file (no T_cam_lidar)")
    ext = load_seed(args.result)
    seed = Extrinsic.from_matrix(np.array(result["seed"]["T_cam_lidar"])) if isinstance(result.get("seed"), dict) else None
    pair = tuple(a for a in args.pair.split(",") if a)
    if len(pair) != 2:
        raise InputError(None, f"--pair takes two axes, got {args.pair!r}")
    studies = [(p, common.read_doc(p)) for p in args.study]
    if args.scenes is None and result.get("scenes_dir") and Path(result["scenes_dir"]).is_dir():
        args.scenes = Path(result["scenes_dir"])
    args.seed = None
    ss = common.load_scenes(args)
    seed = seed or ss.seed
    try:
        settings = settings_from_result(result)
    except (ValueError, TypeError) as exc:
        raise InputError(args.result, f"bad optimiser settings ({exc})") from None
    held = split_scenes(ss.names, args.held_out) if args.held_out else None
    inp = ReportInputs(ss, result, args.result, settings, seed, ext, load_candidates(args.candidate),
                       parse_groups(args.group) or None, held, common.truth(args, ss.root), studies, pair,  # type: ignore[arg-type]
                       args.steps, wanted_mm=args.wanted_mm, wanted_deg=args.wanted_deg)
    page, data = build(inp, on_progress=lambda msg: None)
    backup = common.write(args.out, page.encode())
    for w in data["guardrails"]:
        print(f"warning: {w['message']}", file=sys.stderr)
    print(f"report written to {args.out} ({len(page) / 1e6:.1f} MB)" + (f"; previous file kept as {backup}" if backup else ""))
    return 0
