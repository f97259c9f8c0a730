"""Wall time of a repeatability study: local processes against a Dask LocalCluster (issue 9).

    python benchmarks/bench_qa_study.py --scenes DIR [--runs 40] [--workers 2]

DIR: e.g. ``l2e-studio synth --out DIR`` (40 full-size scenes). Both runs use the same specs
(seeds perturbed uniformly by +-5 cm / +-2 deg per axis, all scenes, SLSQP) through the same
:func:`l2e_studio.qa.studies.study`; only the executor differs. Each worker loads the folder once.
Objective threads per worker process: 1 (L2E_THREADS=1), so both use the cores alike.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

os.environ.setdefault("L2E_THREADS", "1")

from l2e_studio.calibrate import CalibrationSettings  # noqa: E402
from l2e_studio.qa import AXES  # noqa: E402
from l2e_studio.qa.studies import StackSource, repeatability_specs, study  # noqa: E402
from l2e_studio.scenes import load_scene_folder  # noqa: E402
from l2e_studio.synth import read_truth  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", required=True)
    ap.add_argument("--runs", type=int, default=40)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--only", choices=("local", "dask"))
    a = ap.parse_args()
    ss = load_scene_folder(a.scenes)
    truth = read_truth(os.path.join(a.scenes, "truth.yaml"))
    specs = repeatability_specs(ss.seed, a.runs, 0.05, 2.0, ["SLSQP"], len(ss.scenes), rng_seed=0)
    source = StackSource(folder=a.scenes)
    results = {}
    if a.only in (None, "local"):
        t = time.perf_counter()
        results["local"] = study("repeatability", source, ss.seed, CalibrationSettings(), specs, 0.05, 2.0, truth=truth,
                                 workers=a.workers)
        print(f"local processes: {time.perf_counter() - t:.1f} s wall ({results['local'].executor})", flush=True)
    if a.only in (None, "dask"):
        from distributed import LocalCluster

        t0 = time.perf_counter()
        with LocalCluster(n_workers=a.workers, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
            t = time.perf_counter()
            results["dask"] = study("repeatability", source, ss.seed, CalibrationSettings(), specs, 0.05, 2.0, truth=truth,
                                    dask=cluster.scheduler_address)
            print(f"dask LocalCluster: {time.perf_counter() - t:.1f} s wall ({results['dask'].executor}; cluster start "
                  f"{t - t0:.1f} s not counted)", flush=True)
    for name, res in results.items():
        s = res.summary()["methods"]["SLSQP"]
        p = res.params()
        print(f"{name}: {len(res.runs)} runs, run time {s['seconds_mean']:.2f} +- {s['seconds_std']:.2f} s, "
              f"evaluations {s['evaluations_mean']:.0f}; result - truth mean +- std: "
              + ", ".join(f"{ax} {p[:, k].mean():+.3f} +- {p[:, k].std(ddof=1):.3f}" for k, ax in enumerate(AXES)))
    if len(results) == 2:
        print("largest difference between the two executors' results:",
              float(np.abs(results["local"].params() - results["dask"].params()).max()))


if __name__ == "__main__":
    main()
