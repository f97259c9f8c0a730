"""Where the search alone ends from seeds off the reference (stop 42): its reach, without the verdict.

For each rig and seed level, the seeds of ``bench_realdata.py`` (the same perturbations) are
handed to :func:`l2e_studio.calibrate.refine` on the stack the bench calibrates (aimed at the
seed): one line per rig and level with how many ends lie within ``--found`` deg of the reference,
each end's rotation error, its final score as a share of the reference's, and the median
seconds a search takes. ``--grid`` adds, per seed, how the grid's own starts fared: the rank of
the grid point nearest the reference by the coarsest score (the ranking before stop 42), and
how many of the grid's middle-stage climbs end within 1 deg of it.

To compare with another commit's search, run this file with that commit's package first on
``PYTHONPATH`` (``git worktree add /tmp/old REV``; ``PYTHONPATH=/tmp/old python ...``).

    L2E_REALDATA=../shared/realdata python benchmarks/study_search.py --rigs kitti,manual --levels 2,5
    python benchmarks/study_search.py --rigs none --synthetic os128 --synthetic-scenes 8 --levels 1,2
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_realdata import LEVELS  # noqa: E402
from realdata_rigs import load_rigs, perturbations, synthetic_rigs  # noqa: E402

from l2e_studio.calibrate import CalibrationSettings, refine, stack_scenes  # noqa: E402


def grid_detail(stack, seed, reference, settings) -> str:
    """The rank of the grid point nearest ``reference`` by the coarsest score, and how many of
    the grid's middle-stage climbs end within 1 deg of ``reference``."""
    from l2e_studio import calibrate as cal

    stages = settings.schedule(stack.camera.width, stack.camera.height)
    coarse = stack.with_sigma(stages[0].sigma, stages[0].scale).objective(seed, max_points=cal.GRID_POINTS)
    grid = cal.grid_rotations()
    deltas = [np.concatenate([np.zeros(3), dw]) for dw in grid]
    values = np.array([coarse.value(d) for d in deltas])
    errors = np.array([coarse.extrinsic(d).error_to(reference)[0] for d in deltas])
    rank = int(np.flatnonzero(np.argsort(values)[::-1] == np.argmin(errors))[0])
    scale = np.array([settings.translation_bound] * 3 + [np.radians(settings.rotation_bound_deg)] * 3)
    run = cal._Run(stack, seed, settings, scale, np.ones(6, bool), stages, None, None, time.perf_counter())
    middle = stack.with_sigma(stages[1].sigma, stages[1].scale).objective(seed, max_points=cal.GRID_POINTS)
    near = sum(middle.extrinsic(run.climb_objective(middle, 1, d)[0]).error_to(reference)[0] < 1.0 for d in deltas)
    return f"nearest point {errors.min():.1f} deg, coarse rank {rank + 1}/{len(grid)}, {near} climbs end < 1 deg"


def study(rig, levels, runs: int, found: float, grid: bool) -> list[dict]:
    settings = CalibrationSettings()
    stack = stack_scenes(rig.scenes, rig.camera, rig.reference,
                         CalibrationSettings(translation_bound=0.5, rotation_bound_deg=20.0))
    rows = []
    for level in levels:
        deg, m = LEVELS[level]
        li = list(LEVELS.values()).index((deg, m))  # bench_realdata's seeds
        errors, shares, seconds = [], [], []
        for k, (dt, dr) in enumerate(perturbations(runs, deg, m, 1000 + li)):
            seed = rig.reference.perturbed(dt, dr)
            aimed = stack.aimed_at(seed)
            t = time.perf_counter()
            end = refine(aimed, seed, settings)
            seconds.append(time.perf_counter() - t)
            final = aimed.with_sigma(settings.sigma)
            errors.append(float(end.error_to(rig.reference)[0]))
            shares.append(float(final.score(end, per_scene=False)[0] / final.score(rig.reference, per_scene=False)[0]))
            if grid:
                print(f"    #{k}: {errors[-1]:.2f} deg; {grid_detail(aimed, seed, rig.reference, settings)}", flush=True)
        e = np.array(errors)
        print(f"{rig.name:24s} {deg:g} deg: found {int(np.sum(e < found)):2d}/{len(e)}  ends "
              + " ".join(f"{x:.2f}" for x in e) + "  share " + " ".join(f"{s:.2f}" for s in shares)
              + f"  {np.median(seconds):.2f} s", flush=True)
        rows.append(dict(rig=rig.name, level=level, errors=errors, shares=shares, seconds=seconds))
    return rows


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rigs", default="manual,3,kitti,kitti_odometry_00", help="dev rigs (none: only --synthetic)")
    p.add_argument("--synthetic", default="", help="synthetic lidars (synth.lidars.LIDARS names), comma-separated")
    p.add_argument("--synthetic-scenes", type=int, default=8)
    p.add_argument("--levels", default="1,2,5", help="seed levels (bench_realdata.LEVELS keys)")
    p.add_argument("--runs", type=int, default=10, help="seeds per rig and level")
    p.add_argument("--found", type=float, default=0.5, help="an end this close to the reference (deg) is found")
    p.add_argument("--grid", action="store_true", help="also the grid's starts, per seed")
    p.add_argument("--save", type=Path)
    a = p.parse_args()
    rigs = [] if a.rigs == "none" else load_rigs(a.rigs.split(","))
    if a.synthetic:
        rigs += synthetic_rigs(a.synthetic.split(","), [a.synthetic_scenes])
    if not rigs:
        sys.exit("no rig to study: ../shared/realdata is absent (or --rigs none without --synthetic)")
    rows = [row for rig in rigs for row in study(rig, [int(x) for x in a.levels.split(",")], a.runs, a.found, a.grid)]
    if a.save:
        a.save.write_text(json.dumps(rows))


if __name__ == "__main__":
    main()
