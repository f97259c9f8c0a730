"""``l2e-studio heldout``: the paper's Table III -- candidate calibrations scored per scene, per
group and on held-out scenes, with the difference between any two."""

from __future__ import annotations

import argparse
from pathlib import Path


NAME = "heldout"
HELP = "Score candidate calibrations scene by scene, per group and on held-out scenes (the paper's Table III)."


def add_arguments(p: argparse.ArgumentParser) -> None:
    from . import _qa_common as common

    common.add_scene_args(p)
    p.add_argument("--candidate", action="append", default=[], metavar="NAME=FILE",
                   help="a calibration to score (result file, seed file, previous release...); repeatable")
    p.add_argument("--group", action="append", default=[], metavar="NAME=GLOB[,GLOB]",
                   help="a group of scenes by name pattern, e.g. checker='checker*'; repeatable")
    p.add_argument("--held-out", action="append", default=[], metavar="GLOB", help="scenes held out of the calibration")
    p.add_argument("--held-out-fraction", type=float, help="hold out this random share of the scenes instead")
    p.add_argument("--calibrate", action="store_true",
                   help="calibrate on the scenes not held out (from the seed) and score that result as 'result'")
    p.add_argument("--method", default="SLSQP", help="optimiser for --calibrate (default: %(default)s)")
    p.add_argument("--rng-seed", type=int, default=0)
    p.add_argument("--out", type=Path, help="write the table as YAML or JSON")


def run(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table
    from ..calibrate import calibrate, stack_scenes
    from ..qa.heldout import Candidate, load_candidates, parse_groups, score, split_scenes
    from . import _qa_common as common

    settings = common.settings(args, method=args.method)
    groups = parse_groups(args.group)
    candidates = load_candidates(args.candidate)
    if args.out:
        common.check_writable(args.out)
    ss = common.load_scenes(args)
    held = split_scenes(ss.names, args.held_out, args.held_out_fraction, args.rng_seed)
    cands = [Candidate("seed", ss.seed, ss.seed_source or "seed")]
    truth = common.truth(args, ss.root)
    stack = stack_scenes(ss.scenes, ss.camera, ss.seed, settings)
    if args.calibrate:
        train = [i for i, h in enumerate(held) if not h]
        res = calibrate(stack.subset(train), None, ss.seed, settings)
        cands.append(Candidate("result", res.extrinsic, f"calibrated on {len(train)} scenes"))
    if truth is not None:
        cands.append(Candidate("truth", truth, "truth.yaml"))
    cands += candidates
    table = score(stack, cands, groups, held)
    con = Console()
    t = Table(title="MI per scene (nats), pooled per group")
    t.add_column("scene")
    for c in cands:
        t.add_column(c.name, justify="right")
    for row in table.rows():
        t.add_row(*[escape(c) for c in row])
    con.print(t)
    d = Table(title="differences")
    for col in ("a", "b", "rotation deg", "translation mm"):
        d.add_column(col, justify="right")
    for (a, b), v in table.differences.items():
        d.add_row(a, b, f"{v['rotation_deg']:.4f}", f"{v['translation_mm']:.2f}")
    con.print(d)
    if args.out:
        common.write(args.out, common.dump(table.to_dict(), args.out))
        con.print(f"table written to {args.out}", highlight=False)
    return 0
