"""``l2e-studio study repeatability|scenes|bootstrap``: many calibrations in parallel (local
processes, or a Dask cluster with ``--dask tcp://host:8786``) and their spread."""

from __future__ import annotations

import argparse
import sys
import threading
from pathlib import Path

from ..errors import InputError

NAME = "study"
HELP = "Repeatability (perturbed seeds), scene-count and scene-bootstrap studies, in parallel processes or on Dask."


def add_arguments(p: argparse.ArgumentParser) -> None:
    from .calibrate import METHODS  # the CLI's copy: no engine import for --help
    from . import _qa_common as common

    p.add_argument("kind", choices=("repeatability", "scenes", "bootstrap"),
                   help="repeatability: N runs from perturbed seeds; scenes: spread per scene count; "
                        "bootstrap: N recalibrations from --centre on random halves of the scenes")
    common.add_scene_args(p)
    p.add_argument("-n", "--runs", type=int, default=20, help="runs (per optimiser, or per scene count) (default: %(default)s)")
    p.add_argument("--noise-m", type=float, default=0.05, help="seed noise per translation axis, uniform +-m (default: %(default)s)")
    p.add_argument("--noise-deg", type=float, default=2.0, help="seed noise per rotation axis, uniform +-deg (default: %(default)s)")
    p.add_argument("--methods", default="SLSQP", help=f"comma-separated optimisers ({', '.join(METHODS)}) (default: %(default)s)")
    p.add_argument("--subset", type=int, help="repeatability: each run on this many random scenes")
    p.add_argument("--counts", default="", help="scenes: comma-separated scene counts (default: 1, 2, 4 ... all)")
    p.add_argument("--centre", type=Path, help="extrinsic the seeds are perturbed around (default: the folder's seed)")
    p.add_argument("--workers", type=int, help="local worker processes (default: one per core)")
    p.add_argument("--dask", metavar="ADDRESS", help="run on the Dask scheduler at ADDRESS (tcp://host:8786)")
    p.add_argument("--rng-seed", type=int, default=0)
    p.add_argument("--out", type=Path, default=Path("l2e_study.json"), help="study file, JSON or YAML (default: %(default)s)")
    p.add_argument("--quiet", action="store_true")


def run(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
    from ..io.cameras import load_seed
    from ..qa.studies import StackSource, check_study_args, repeatability_specs, scene_count_specs, study
    from ..qa.uncertainty import half_sample_specs
    from . import _qa_common as common

    methods = [m for m in args.methods.split(",") if m]
    check_study_args(args.runs, args.noise_m, args.noise_deg, methods)
    if args.workers is not None and args.workers < 1:
        raise InputError(None, f"--workers must be >= 1, got {args.workers}")
    settings = common.settings(args, method=methods[0])
    common.check_writable(args.out)
    common.check_files(args)
    if args.centre is not None and not args.centre.is_file():
        raise InputError(args.centre, "centre file does not exist")
    ss = common.load_scenes(args)
    n_scenes = len(ss.scenes)
    check_study_args(args.runs, args.noise_m, args.noise_deg, methods, args.subset, n_scenes)
    centre = load_seed(args.centre) if args.centre else ss.seed
    truth = common.truth(args, ss.root)
    if args.kind == "repeatability":
        specs = repeatability_specs(centre, args.runs, args.noise_m, args.noise_deg, methods, n_scenes, args.subset, args.rng_seed)
    elif args.kind == "scenes":
        try:
            counts = [int(c) for c in args.counts.split(",") if c] or _default_counts(n_scenes)
        except ValueError:
            raise InputError(None, f"--counts must be comma-separated integers, got {args.counts!r}") from None
        specs = scene_count_specs(centre, counts, args.runs, args.noise_m, args.noise_deg, n_scenes, methods[0], args.rng_seed)
    else:
        specs = half_sample_specs(centre, n_scenes, args.runs, args.rng_seed, methods[0])
    source = StackSource(folder=str(ss.root), seed_file=str(args.seed) if args.seed else None,
                         camera_file=str(args.camera) if args.camera else None)
    err = Console(stderr=True)
    cancel = threading.Event()
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  console=err, disable=args.quiet or not err.is_terminal) as prog:
        task = prog.add_task(f"{args.kind} study", total=len(specs))
        try:
            res = study("scenes" if args.kind == "scenes" else args.kind, source, centre, settings, specs, args.noise_m,
                        args.noise_deg, truth=truth, dask=args.dask, workers=args.workers,
                        on_progress=lambda done, total, run: prog.update(task, completed=done), cancel=cancel)
        except KeyboardInterrupt:
            cancel.set()
            raise
    data = res.to_dict()
    data["summary"]["kind"] = args.kind
    data["summary"]["scenes_dir"] = str(ss.root)
    backup = common.write(args.out, common.dump(data, args.out))
    _print(data["summary"], res)
    print(f"study written to {args.out}" + (f" (previous file kept as {backup})" if backup else ""))
    return 0


def _default_counts(n: int) -> list[int]:
    out, c = [], 1
    while c < n:
        out.append(c)
        c *= 2
    return out + [n]


def _print(summary: dict, res) -> None:
    from rich.console import Console
    from rich.table import Table
    from ..qa import AXES, UNITS

    con = Console()
    t = Table(title=f"{summary['kind']}: {summary['runs']} runs relative to the {summary['reference']}, "
                    f"wall {summary['wall_seconds']:.1f} s on {summary['executor']}")
    t.add_column("optimiser")
    for a, u in zip(AXES, UNITS):
        t.add_column(f"{a} ({u})", justify="right")
    t.add_column("run time (s)", justify="right")
    for m, s in summary["methods"].items():
        t.add_row(m, *[f"{s['mean'][a]:.3f} +- {s['std'][a] if s['std'][a] is not None else float('nan'):.3f}" for a in AXES],
                  f"{s['seconds_mean']:.2f} +- {s['seconds_std'] or 0:.2f}")
    con.print(t)
    for k, v in (summary.get("scene_counts") or {}).items():
        con.print(f"{k:4d} scenes: std " + "  ".join(f"{a} {v['std'][a] if v['std'][a] is not None else float('nan'):.4f}" for a in AXES), highlight=False)
    if res.cancelled:
        print("warning: the study was cancelled; the file holds the runs that finished", file=sys.stderr)
