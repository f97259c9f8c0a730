"""Accuracy and speed of the calibration engine on synthetic full-size scenes (issue 2).

    python benchmarks/bench_engine.py                     # 40 scenes, 40 perturbed-seed runs
    python benchmarks/bench_engine.py --runs 5            # quicker
    python benchmarks/bench_engine.py --scaling           # + cost versus scene count (5..80)
    python benchmarks/bench_engine.py --cli               # + the whole `l2e-studio calibrate` process
    python benchmarks/bench_engine.py --realism           # the harder synthetic mode (synth --realism)
    python benchmarks/bench_engine.py --runs 4 --cli --reference   # + side by side with the paper's
                                                          # computation (reference_l2e.py): ratios

The synthetic dataset (the paper's sensors: 1280x720 event map, ~75k lidar points per scan) is
written once to ``benchmarks/out/synth<N>`` and reused. Seeds follow the paper's protocol: the
true extrinsic's translation and rotation vector each perturbed uniformly by up to 0.1 m and
0.1 rad per axis. A run passes when it lands within 0.1 deg and 1 cm of the truth.

Absolute times depend on the machine (its CPU is printed first, with the load average, which
should be near 0): published figures are the ratios to ``--reference``, measured in the same
run on the same data: ``reference_l2e.py`` does the paper's computation the plain way (every point,
every scene, each evaluation; SLSQP with numerical gradients), written from the paper's text.
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from l2e_studio.calibrate import CalibrationSettings, calibrate, stack_scenes
from l2e_studio.geometry import Extrinsic
from l2e_studio.scenes import load_scene_folder
from l2e_studio.synth import SynthConfig, config_with, perturb, read_truth, write_dataset
from l2e_studio.verdict import judge

OUT = Path(__file__).resolve().parent / "out"


def dataset(n: int, realism: bool = False) -> Path:
    folder = OUT / (f"synth{n}" + ("_realism" if realism else ""))
    if not (folder / "truth.yaml").is_file():
        t = time.perf_counter()
        write_dataset(folder, config_with(SynthConfig(), n_scenes=n, realism=realism), overwrite=True)
        print(f"wrote {n} synthetic scenes to {folder} in {time.perf_counter() - t:.1f} s")
    return folder


def timed(fn, repeat: int = 5) -> float:
    fn()
    t = time.perf_counter()
    for _ in range(repeat):
        fn()
    return (time.perf_counter() - t) / repeat


def perturbed_seed(truth: Extrinsic, rng: np.random.Generator) -> Extrinsic:
    return Extrinsic(truth.rotvec + rng.uniform(-0.1, 0.1, 3), truth.translation + rng.uniform(-0.1, 0.1, 3))


def cpu_name() -> str:
    """The CPU's model name (``lscpu``'s), the core count this process may use, the load average."""
    name = platform.processor() or "unknown CPU"
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, check=True).stdout
        name = next(l.split(":", 1)[1].strip() for l in out.splitlines() if l.startswith("Model name"))
    except (OSError, subprocess.CalledProcessError, StopIteration):
        pass
    return f"{name}, {len(os.sched_getaffinity(0))} cores, load average {os.getloadavg()[0]:.1f}"


def load(folder: Path):
    t = time.perf_counter()
    scene_set = load_scene_folder(folder, use_cache=False)
    cold = time.perf_counter() - t
    load_scene_folder(folder)  # fills the cache
    t = time.perf_counter()
    scene_set = load_scene_folder(folder)
    warm = time.perf_counter() - t
    return scene_set, cold, warm


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", type=int, default=40)
    ap.add_argument("--runs", type=int, default=40)
    ap.add_argument("--method", default="SLSQP")
    ap.add_argument("--scaling", action="store_true")
    ap.add_argument("--cli", action="store_true")
    ap.add_argument("--realism", action="store_true", help="the harder synthetic mode")
    ap.add_argument("--reference", action="store_true",
                    help="also time the paper's computation (reference_l2e.py) on the same data and seed: ratios")
    ap.add_argument("--seed-level", help="DEG,M: seeds exactly this far off in a random direction "
                                         "(default: the paper's uniform 0.1 m / 0.1 rad per axis)")
    args = ap.parse_args()

    print(f"CPU: {cpu_name()}")
    folder = dataset(args.scenes, args.realism)
    truth = read_truth(folder / "truth.yaml")
    scene_set, cold, warm = load(folder)
    print(f"load {args.scenes} scenes: {cold:.2f} s from text, {warm:.2f} s from the cache")

    settings = CalibrationSettings(method=args.method)
    t = time.perf_counter()
    stack = stack_scenes(scene_set.scenes, scene_set.camera, scene_set.seed, settings)
    print(f"stack: {stack.n_points} points that can reach the image, built in {time.perf_counter() - t:.2f} s")
    print(f"one MI evaluation (paper estimator, all scenes pooled): {1000 * timed(lambda: stack.mi(truth, per_scene=False)):.1f} ms")
    print(f"  with per-scene MI as well: {1000 * timed(lambda: stack.mi(truth)):.1f} ms")
    zero = np.zeros(6)
    final_budget = settings.schedule(stack.camera.width, stack.camera.height)[-1].max_points
    for label, budget in (("every point in the image", None), ("the final stage's budget", final_budget)):
        obj = stack.objective(truth, max_points=budget)
        print(f"smooth objective, {label} ({obj.stack.n_points} points): value {1000 * timed(lambda: obj.value(zero)):.1f} ms, "
              f"value+gradient {1000 * timed(lambda: obj.value_and_grad(zero)):.1f} ms")

    rng = np.random.default_rng(2023)
    rows = []
    level = tuple(float(v) for v in args.seed_level.split(",")) if args.seed_level else None
    for i in range(args.runs):
        seed = perturb(truth, level[0], level[1], rng) if level else perturbed_seed(truth, rng)
        fresh = replace(stack)  # the stack as a new process builds it: none of its smoothings prepared yet
        res = calibrate(fresh, None, seed, settings)
        verdict = judge(fresh, res, settings)
        deg, m = res.extrinsic.error_to(truth)
        ok = deg <= 0.1 and m <= 0.01
        rows.append((deg, m, res.seconds, res.evaluations, res.seconds + verdict.seconds, ok, verdict.status))
        sdeg, sm = seed.error_to(truth)
        print(f"run {i:2d}: seed {sdeg:5.2f} deg {100 * sm:5.1f} cm -> {deg:.4f} deg {1000 * m:5.2f} mm  "
              f"{res.evaluations:3d} evals {res.seconds:5.2f} s  {'ok' if ok else 'MISS'}  verdict {verdict.status} "
              f"({verdict.seconds:.2f} s){'' if verdict.trusted else ': ' + '; '.join(verdict.reasons)}", flush=True)
    a = np.array([r[:5] for r in rows])
    n_ok = sum(r[5] for r in rows)
    trusted = sum(r[6] == "trusted" for r in rows)
    print(f"\naccuracy: {n_ok}/{len(rows)} runs within 0.1 deg and 1 cm; rotation error median {np.median(a[:, 0]):.4f} "
          f"max {a[:, 0].max():.4f} deg; translation error median {1000 * np.median(a[:, 1]):.2f} max {1000 * a[:, 1].max():.2f} mm")
    print(f"optimisation wall time: median {np.median(a[:, 2]):.2f} s, max {a[:, 2].max():.2f} s; "
          f"evaluations median {np.median(a[:, 3]):.0f}")
    print(f"optimisation + verdict: median {np.median(a[:, 4]):.2f} s, max {a[:, 4].max():.2f} s; "
          f"verdict trusted {trusted}/{len(rows)}")
    print(f"peak memory (max RSS) so far: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")

    if args.scaling:
        print("\nscenes  points  eval_ms  optimisation_s")
        for n in (5, 10, 20, 40, 80):
            sub = load_scene_folder(dataset(max(n, args.scenes)) if n > args.scenes else folder)
            st = stack_scenes(sub.scenes[:n], sub.camera, sub.seed, settings)
            ev = timed(lambda: st.mi(truth, per_scene=False), 3)
            res = calibrate(st, None, perturbed_seed(truth, np.random.default_rng(n)), settings)
            print(f"{n:6d} {st.n_points:8d} {1000 * ev:7.1f} {res.seconds:8.2f}", flush=True)

    whole = None
    if args.cli:
        out = OUT / "cli_result.yaml"
        out.unlink(missing_ok=True)
        # GNU time reports the child's own peak (ru_maxrss of a child forked from this large
        # process would count the parent's pages it shares until exec)
        cmd = ["/usr/bin/time", "-v", sys.executable, "-m", "l2e_studio", "calibrate", "--scenes", str(folder),
               "--out", str(out), "--quiet"]
        t = time.perf_counter()
        proc = subprocess.run(cmd, check=True, capture_output=True, text=True)
        wall = time.perf_counter() - t
        peak = next((int(l.split(":")[1]) / 1024 for l in proc.stderr.splitlines() if "Maximum resident" in l), float("nan"))
        print(f"\nwhole `l2e-studio calibrate` process on {args.scenes} scenes: {wall:.2f} s, peak memory {peak:.0f} MB")
        whole = wall

    if args.reference:
        side_by_side(folder, truth, stack, settings, rows, cold, whole)
    print(f"CPU at the end: {cpu_name()}")


def side_by_side(folder: Path, truth: Extrinsic, stack, settings, rows, our_load: float, our_whole: float | None) -> None:
    """The paper's computation on the same scenes and the first run's seed; ours / its time as ratios."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import reference_l2e as ref

    t = time.perf_counter()
    scenes = ref.load(folder)
    ref_load = time.perf_counter() - t
    ref_eval = timed(lambda: ref.mi(truth.params, scenes), 2)
    our_eval = timed(lambda: stack.mi(truth, per_scene=False))
    seed = perturbed_seed(truth, np.random.default_rng(2023))  # the first run's seed
    print(f"\nreference (the paper's computation, reference_l2e.py), {len(scenes.maps)} scenes, "
          f"from run 0's seed: calibrating...", flush=True)
    res = ref.calibrate(scenes, seed.params)
    deg, m = Extrinsic.from_params(res.theta).error_to(truth)
    t = time.perf_counter()
    ours = calibrate(stack, None, seed, settings)
    verdict = judge(stack, ours, settings)
    our_run = time.perf_counter() - t
    print(f"  reference: load {ref_load:.2f} s; one MI evaluation {1000 * ref_eval:.0f} ms; calibration "
          f"{res.seconds:.1f} s ({res.evaluations} evaluations) -> {deg:.3f} deg {1000 * m:.1f} mm from the truth")
    odeg, om = ours.extrinsic.error_to(truth)
    print(f"  ours, same seed: one MI evaluation {1000 * our_eval:.0f} ms; optimisation {ours.seconds:.2f} s "
          f"({ours.evaluations} evaluations) -> {odeg:.3f} deg {1000 * om:.1f} mm; + verdict {our_run - ours.seconds:.2f} s")
    print(f"  ratios (reference time / ours): one MI evaluation {ref_eval / our_eval:.0f}x; "
          f"optimisation {res.seconds / ours.seconds:.0f}x; optimisation (ours with its verdict) "
          f"{res.seconds / our_run:.0f}x")
    ref_whole = ref_load + res.seconds
    if our_whole is not None:
        print(f"  whole process: reference load + optimise {ref_whole:.1f} s; ours `l2e-studio calibrate` "
              f"(load, optimise, judge, write) {our_whole:.1f} s: {ref_whole / our_whole:.0f}x")
    else:
        ours_whole = our_load + our_run
        print(f"  whole process: reference load + optimise {ref_whole:.1f} s; ours in this process (load from "
              f"text, optimise, judge) {ours_whole:.1f} s: {ref_whole / ours_whole:.0f}x (--cli times the real command)")


if __name__ == "__main__":
    main()
