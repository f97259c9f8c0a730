"""Do the repeatability spread, the uncertainty estimates and the true error agree (issue 9)?

A pool of synthetic scenes with a known extrinsic; N calibrations, each from a seed perturbed
uniformly (+-5 cm, +-2 deg per axis) on a random subset of K scenes (the repeatability study with
scene subsets). Per parameter (mm, deg, camera frame) it prints:

* spread: the standard deviation of the N results (the repeatability study);
* curvature: the RMS over the runs of each run's Hessian + scene-jackknife std (qa.uncertainty.curvature);
* bootstrap: the RMS over the first B runs of the std of 12 recalibrations on random halves of
  that run's scenes (qa.uncertainty.half_sample_specs);
* true error: the RMS over the runs of result - truth.

    python benchmarks/bench_qa_agreement.py [--pool 48] [--subset 12] [--runs 24] [--width 640] [--points 20000]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from l2e_studio.calibrate import CalibrationSettings, stack_scenes
from l2e_studio.geometry import Extrinsic
from l2e_studio.qa import AXES, UNITS, studies, uncertainty
from l2e_studio.scenes import Scene
from l2e_studio.synth import SynthConfig, config_with, make_rig, make_scene


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--pool", type=int, default=48)
    ap.add_argument("--subset", type=int, default=12)
    ap.add_argument("--runs", type=int, default=24)
    ap.add_argument("--bootstrap-runs", type=int, default=6)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--points", type=int, default=20000)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=5)
    a = ap.parse_args()
    cfg = config_with(SynthConfig(), n_scenes=a.pool, width=a.width, height=a.width * 9 // 16, points_per_scan=a.points, seed=a.seed)
    camera, truth, seed = make_rig(cfg)
    scenes = []
    for i in range(a.pool):
        p, it, m = make_scene(cfg, i, truth, camera)
        scenes.append(Scene(f"s{i:03d}", p, it, m.astype(np.float32)))
    st = CalibrationSettings()
    stack = stack_scenes(scenes, camera, seed, st)
    specs = studies.repeatability_specs(seed, a.runs, 0.05, 2.0, ["SLSQP"], a.pool, a.subset, rng_seed=1)
    t0 = time.perf_counter()
    with studies.open_executor(workers=a.workers) as (ex, desc):
        res = studies.study("repeatability", studies.StackSource(stack=stack), seed, st, specs, 0.05, 2.0, truth=truth, executor=ex)
        P = res.params()
        curv, boot = [], []
        for k, (r, sp) in enumerate(zip(res.runs, specs)):
            ext = Extrinsic.from_matrix(np.array(r["T_cam_lidar"]))
            sub = stack.subset(list(sp.subset))
            curv.append(uncertainty.curvature(sub, ext).std)
            if k < a.bootstrap_runs:
                hs = uncertainty.half_sample_specs(ext, sub.n_scenes, 12, rng_seed=k)
                b = studies.study("bootstrap", studies.StackSource(stack=sub), ext, st, hs, 0, 0, truth=truth, executor=ex)
                boot.append(uncertainty.from_half_samples(b.params()).std)
    wall = time.perf_counter() - t0
    spread = P.std(0, ddof=1)
    err = np.sqrt((P ** 2).mean(0))
    curv = np.sqrt((np.array(curv) ** 2).mean(0))
    boot = np.sqrt((np.array(boot) ** 2).mean(0)) if boot else np.full(6, np.nan)
    print(f"{a.pool}-scene pool {a.width}x{a.width * 9 // 16}, {a.points} points/scan; {a.runs} runs on {a.subset}-scene subsets "
          f"(+-5 cm / +-2 deg seeds); bootstrap on {len(boot) if np.ndim(boot) else 0 or a.bootstrap_runs} runs; {desc}; {wall:.0f} s")
    print("| param | spread (repeatability) | curvature | bootstrap | RMS true error | curv/spread | boot/spread | err/spread | curv/err |")
    print("|---|---|---|---|---|---|---|---|---|")
    for k, ax in enumerate(AXES):
        print(f"| {ax} ({UNITS[k]}) | {spread[k]:.4g} | {curv[k]:.4g} | {boot[k]:.4g} | {err[k]:.4g} | "
              f"{curv[k] / spread[k]:.2f} | {boot[k] / spread[k]:.2f} | {err[k] / spread[k]:.2f} | {curv[k] / err[k]:.2f} |")


if __name__ == "__main__":
    main()
