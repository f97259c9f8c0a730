"""Generate synthetic scenes, time them, and check that MI pins the true extrinsic down.

    python benchmarks/make_synthetic.py --scenes 10                # time generation (in memory)
    python benchmarks/make_synthetic.py --scenes 20 --sweep        # + MI sweeps around the truth
    python benchmarks/make_synthetic.py --scenes 40 --calibrate 5  # + calibrations from perturbed seeds
    python benchmarks/make_synthetic.py --out /tmp/synth40         # also write the folder

Sweeps move one parameter of the truth at a time (camera-frame translation x, y, z in mm and
rotation about x, y, z in degrees) and print the paper's MI (``SceneStack.mi``) relative to the
truth, plus where the peak lies on a fine grid. Calibrations start from seeds perturbed uniformly
by up to 0.1 m and 0.1 rad per axis (the paper's protocol) and print the final errors.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from l2e_studio.calibrate import CalibrationSettings, calibrate
from l2e_studio.objective import SceneStack
from l2e_studio.scenes import Scene
from l2e_studio.synth import SynthConfig, config_with, make_rig, make_scene, write_dataset


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", type=int, default=10)
    ap.add_argument("--width", type=int)
    ap.add_argument("--height", type=int)
    ap.add_argument("--points", type=int)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-distortion", action="store_true")
    ap.add_argument("--sigma", type=float, default=5.0, help="map smoothing for --sweep and --bias (px)")
    ap.add_argument("--sweep", action="store_true", help="MI sweeps of each parameter around the truth")
    ap.add_argument("--bias", action="store_true",
                    help="where the smooth MI objective peaks, climbing from the truth (points >= 15 px inside)")
    ap.add_argument("--calibrate", type=int, default=0, metavar="N", help="N calibrations from perturbed seeds")
    ap.add_argument("--out", help="also write the dataset to this folder (overwrites)")
    args = ap.parse_args()

    config = config_with(SynthConfig(), n_scenes=args.scenes, width=args.width, height=args.height,
                         points_per_scan=args.points, seed=args.seed)
    if args.no_distortion:
        config = config_with(config, distortion=False)
    camera, truth, seed = make_rig(config)
    scenes, times = [], []
    for i in range(config.n_scenes):
        t0 = time.perf_counter()
        pts, inten, emap = make_scene(config, i, truth, camera)
        times.append(time.perf_counter() - t0)
        scenes.append(Scene(f"scene_{i:03d}", pts, inten, emap.astype(np.float32)))
    print(f"generated {len(scenes)} scenes {config.width}x{config.height}, ~{config.points_per_scan} points: "
          f"{np.mean(times):.3f} s/scene (min {np.min(times):.3f}, max {np.max(times):.3f})")
    if args.out:
        t0 = time.perf_counter()
        write_dataset(args.out, config, overwrite=True)
        print(f"wrote {args.out} in {time.perf_counter() - t0:.1f} s (generation included)")

    stack = SceneStack.build(scenes, camera, args.sigma, truth, 0.5, 20.0)
    if args.sweep:
        sweep(stack, truth)
    if args.bias:
        objective_peak(stack, camera, truth)
    if args.calibrate:
        run_calibrations(stack, camera, truth, args.calibrate, args.seed)


def sweep(stack: SceneStack, truth) -> None:
    mi0, _ = stack.mi(truth, per_scene=False)
    print(f"MI at truth: {mi0:.5f}")
    coarse_t = np.array([-50, -20, -10, -5, -2, 2, 5, 10, 20, 50]) * 1e-3
    coarse_r = np.array([-2, -1, -0.5, -0.2, -0.1, 0.1, 0.2, 0.5, 1, 2])
    fine_t = np.arange(-10, 10.5, 1.0) * 1e-3
    fine_r = np.arange(-0.2, 0.201, 0.01)
    for k, name in enumerate(["tx", "ty", "tz", "rx", "ry", "rz"]):
        rot = k >= 3
        def mi_at(off: float) -> float:
            d = np.zeros(6)
            d[k] = np.radians(off) if rot else off
            return stack.mi(truth.perturbed(d[:3], d[3:]), per_scene=False)[0]
        coarse = coarse_r if rot else coarse_t
        drops = [mi_at(o) - mi0 for o in coarse]
        fine = fine_r if rot else fine_t
        vals = np.array([mi_at(o) for o in fine])
        peak = fine[int(np.argmax(vals))]
        unit, scale = ("deg", 1.0) if rot else ("mm", 1e3)
        print(f"{name}: fine-grid peak at {peak * scale:+.3f} {unit}; MI - MI(truth) at "
              + ", ".join(f"{o * scale:+g}:{d:+.4f}" for o, d in zip(coarse, drops)))


def objective_peak(stack: SceneStack, camera, truth) -> None:
    """Climb the differentiable MI from the truth itself: the offset found is the estimator's bias
    on this data (occlusions seen from the camera's viewpoint, parallax, smoothing)."""
    from scipy.optimize import minimize

    from l2e_studio.geometry import in_image
    from l2e_studio.objective import MIObjective

    uv, inside = stack.project(truth)
    obj = MIObjective(stack.select(inside & in_image(uv, camera, 15)), truth, truth)
    scale = np.array([0.01] * 3 + [np.radians(0.2)] * 3)

    def f(z):
        mi, g = obj.value_and_grad(z * scale)
        return -mi, -g * scale

    res = minimize(f, np.zeros(6), jac=True, method="L-BFGS-B", bounds=[(-5, 5)] * 6,
                   options=dict(ftol=1e-13, gtol=1e-10, maxiter=300))
    d = res.x * scale
    deg, m = obj.extrinsic(d).error_to(truth)
    print(f"objective peak from the truth: dt {np.round(d[:3] * 1e3, 2)} mm, dw {np.round(np.degrees(d[3:]), 3)} deg "
          f"-> {deg:.3f} deg, {m * 1e3:.1f} mm (MI +{-res.fun - obj.value(np.zeros(6)):.5f})")


def run_calibrations(stack: SceneStack, camera, truth, n: int, seed: int) -> None:
    rng = np.random.default_rng(1000 + seed)
    good = 0
    for i in range(n):
        theta = truth.params + rng.uniform(-0.1, 0.1, 6)
        from l2e_studio.geometry import Extrinsic

        start = Extrinsic.from_params(theta)
        t0 = time.perf_counter()
        res = calibrate(stack, camera, start, CalibrationSettings())
        deg, m = res.extrinsic.error_to(truth)
        sdeg, sm = start.error_to(truth)
        ok = deg < 0.1 and m < 0.01
        good += ok
        print(f"run {i}: seed error {sdeg:.2f} deg {sm * 100:.1f} cm -> {deg:.3f} deg {m * 1000:.1f} mm "
              f"({res.evaluations} evals, {time.perf_counter() - t0:.1f} s){'' if ok else '  MISS'}")
    print(f"{good}/{n} within 0.1 deg and 1 cm")


if __name__ == "__main__":
    main()
