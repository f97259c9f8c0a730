"""Checkerboard calibration on the dev sets: seed spread, verdict, detection, modality agreement,
distance to the references, half-splits against the reported sigma, and time.

    PYTHONPATH=$PWD python benchmarks/bench_target.py [--realdata ../shared/realdata] [--runs 10] [--halves 10]
        [--synthetic 3] [--calibration 30] [--floor 20] [--ablation 12] [--lidars 8] [--synth-dir DIR] [--sets NAMES]

Per set: ``--runs`` seeds 2 deg / 10 cm and as many 5 deg / 20 cm off the reference (uniform
direction, that norm), the spread of the results (max distance to their median, mm / deg), how
many were judged trusted, the share of frames with a detected board; the rles01 frame and event
results against each other; each against reference.yaml and lcecalib_estimate.yaml;
``--halves`` random halves of the frames: spread per axis against the sigma each half reported;
the time for a whole run with detection, cold (no cache) and cached. ``--calibration N``: the
reported sigma against the true error over N synthetic sequences per modality; ``--floor N``:
the median error the lidar's noise allows (Cramer-Rao) against the solver's; ``--ablation N``:
the solver with the true camera boards and with other residual-block scales; ``--lidars N``:
N synthetic sequences per lidar model (16 to 128 beams).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from l2e_studio.geometry import Extrinsic
from l2e_studio.io.cameras import load_seed
from l2e_studio.scenes import load_scene_folder
from l2e_studio.target import calibrate_target, detect_frames, load_target
from l2e_studio.target_verdict import judge_target

SETS = ("lcecalib_rlfs01", "lcecalib_rles01_frame", "lcecalib_rles01_event")


def offset_seed(ref: Extrinsic, deg: float, m: float, rng) -> Extrinsic:
    a, b = rng.standard_normal(3), rng.standard_normal(3)
    return ref.perturbed(m * a / np.linalg.norm(a), np.radians(deg) * b / np.linalg.norm(b))


def correction(centre: Extrinsic, e: Extrinsic) -> np.ndarray:
    dt, dw = centre.delta_to(e)
    return np.concatenate([1000 * dt, np.degrees(dw)])  # mm, deg


def spread(exts: list[Extrinsic]) -> tuple[float, float]:
    """Largest distance of any result to the first (mm, deg)."""
    d = [exts[0].error_to(e) for e in exts]
    return 1000 * max(m for _, m in d), max(g for g, _ in d)


def synthetic_run(modality: str, k: int, folder: Path, lidar: str = "vlp16"):
    """``(truth, result)`` of the synthetic board sequence ``k`` of ``modality`` seen by ``lidar``
    (written into ``folder`` unless already there; None for the result when too few boards were found)."""
    from l2e_studio.cli import main as cli

    out = folder / (f"{modality}{k}" if lidar == "vlp16" else f"{modality}_{lidar}{k}")
    if not (out / "truth.yaml").is_file():
        cli(["synth", "--target", "checkerboard", "--modality", modality, "--lidar", lidar, "--seed", str(k),
             "--out", str(out), "--quiet"])
    ss = load_scene_folder(out)
    truth, board = load_seed(out / "truth.yaml"), load_target(out / "target.yaml")
    try:
        return truth, calibrate_target(ss.scenes, ss.camera, ss.seed, board)
    except ValueError:  # InputError: too few boards found
        return truth, None


def synthetic(count: int, folder: Path) -> None:
    """Median error against the truth of ``count`` synthetic board sequences (10 poses each) per modality."""
    print(f"== synthetic boards (l2e-studio synth --target checkerboard, 10 poses, {count} sequences per modality)")
    for modality in ("frame", "e2vid", "events", "events-moving"):
        errs, trusted, rates, fails, boards = [], 0, [], 0, []
        for k in range(count):
            truth, r = synthetic_run(modality, k, folder)
            boards.append(board_errors(folder / f"{modality}{k}"))
            if r is None:
                fails += 1
                continue
            g, m = truth.error_to(r.extrinsic)
            errs.append((1000 * m, g))
            rates.append(r.target.detection_rate)
            trusted += judge_target(r).status == "trusted"
        med = np.median(np.array(errs), axis=0) if errs else (np.nan, np.nan)
        print(f"   {modality}: median error {med[0]:.2f} mm / {med[1]:.3f} deg over {len(errs)} "
              f"(each: {', '.join(f'{a:.1f} mm {b:.2f} deg' for a, b in errs)}), trusted {trusted}/{count}, "
              f"detected {100 * np.mean(rates) if rates else 0:.0f} %" + (f"; {fails} found too few boards" if fails else ""))
        found = [e for b in boards for e in b if e is not None]
        total = sum(len(b) for b in boards)
        med = np.median(np.array(found), axis=0) if found else (np.nan, np.nan)
        print(f"      boards found {len(found)}/{total} ({100 * len(found) / max(total, 1):.0f} %), camera board pose "
              f"median error {med[0]:.1f} mm / {med[1]:.3f} deg against the truth")


def lidars(count: int, folder: Path) -> None:
    """The method on lidars the dev sets lack: ``count`` synthetic frame-camera sequences per
    lidar model (``synth --lidar``): median and worst error against the truth, how many trusted,
    and how many of the untrusted would have been wrong (off by more than the verdict's limits)."""
    from l2e_studio.synth.lidars import LIDARS
    from l2e_studio.target_verdict import ACCURACY_DEG, ACCURACY_M

    print(f"== lidars ({count} synthetic frame-camera sequences each; error against the truth)")
    for lidar in LIDARS:
        errs, trusted, trusted_wrong = [], 0, 0
        for k in range(count):
            truth, r = synthetic_run("frame", k, folder, lidar)
            if r is None:
                continue
            g, m = truth.error_to(r.extrinsic)
            errs.append((1000 * m, g))
            if judge_target(r).status == "trusted":
                trusted += 1
                trusted_wrong += m > ACCURACY_M or g > ACCURACY_DEG
        e = np.array(errs)
        print(f"   {lidar}: median {np.median(e[:, 0]):.2f} mm / {np.median(e[:, 1]):.3f} deg, worst {e[:, 0].max():.1f} mm / "
              f"{e[:, 1].max():.2f} deg over {len(errs)}; trusted {trusted}, of them beyond {1000 * ACCURACY_M:.0f} mm / "
              f"{ACCURACY_DEG:g} deg: {trusted_wrong}")


def board_errors(out: Path) -> list:
    """Per frame of a synthetic sequence: the detected board pose's error against the true
    one (mm, deg), None where no board was found (the detections are cached)."""
    from l2e_studio.synth.board_dataset import read_board_poses

    ss = load_scene_folder(out)
    poses = read_board_poses(out / "truth.yaml")
    board = load_target(out / "target.yaml")
    errs = []
    for d in detect_frames(ss.scenes, ss.camera, board):
        if not d.found:
            errs.append(None)
            continue
        g, m = _board_pose_error(d.pose, poses[d.name])
        errs.append((1000 * m, g))
    return errs


def _board_pose_error(pose: Extrinsic, truth: Extrinsic) -> tuple[float, float]:
    """deg / m between two board poses, the 180 deg turn of a symmetric grid's numbering allowed."""
    flip = Extrinsic(np.array([0.0, 0.0, np.pi]), np.zeros(3))
    return min((truth.error_to(pose.compose(f)) for f in (Extrinsic(np.zeros(3), np.zeros(3)), flip)),
               key=lambda e: e[0])


def calibration(count: int, folder: Path) -> None:
    """Whether the reported sigma is honest: over ``count`` synthetic sequences per modality, the
    share of |error| / sigma per axis within 1, 2, 3 (a normal error: 68 / 95 / 99.7 %; Student's
    t for 9 dof: 66 / 92 / 98.5 %), and how many sequences judged trusted are off by more than
    the verdict's own limits on some axis."""
    from l2e_studio.target_verdict import ACCURACY_DEG, ACCURACY_M

    print(f"== sigma calibration ({count} synthetic sequences per modality; error / sigma per axis x y z rx ry rz)")
    limits = np.array([ACCURACY_M] * 3 + [np.radians(ACCURACY_DEG)] * 3)
    for modality in ("frame", "e2vid"):
        z, trusted, wrong = [], 0, 0
        for k in range(count):
            truth, r = synthetic_run(modality, k, folder)
            if r is None:
                continue
            dt, dw = r.extrinsic.delta_to(truth)
            err = np.concatenate([dt, dw])
            z.append(err / np.concatenate([r.target.sigma_m, np.radians(r.target.sigma_deg)]))
            if judge_target(r).status == "trusted":
                trusted += 1
                wrong += bool(np.any(np.abs(err) > limits))
        a = np.abs(np.array(z))
        print(f"   {modality}: within 1 / 2 / 3 sigma " + " / ".join(f"{100 * np.mean(a < q):.0f}" for q in (1, 2, 3))
              + " %; per axis within 2: " + " ".join(f"{100 * v:.0f}" for v in np.mean(a < 2, axis=0))
              + " %; RMS error/sigma per axis " + " ".join(f"{v:.2f}" for v in np.sqrt(np.mean(a**2, axis=0)))
              + f"; trusted {trusted}/{len(z)}, of them off by more than the limits "
              f"({1000 * ACCURACY_M:.0f} mm, {ACCURACY_DEG:g} deg per axis): {wrong}")


def information_floor(count: int, folder: Path) -> None:
    """What the lidar's noise allows on ``count`` synthetic frame-camera sequences: the
    Cramer-Rao bound of the extrinsic from every board point against the TRUE board plane and
    every edge point against the true outline (the camera's boards taken as exact; per point the
    frame's measured RMS off its plane, edge points also a uniform azimuth step), as the median
    error a Gaussian of that covariance gives; against the solver's actual median error."""
    from l2e_studio.synth.board_dataset import read_board_poses
    from l2e_studio.target import TargetFrame
    from l2e_studio.target.solve import residuals_at

    print(f"== information floor ({count} synthetic frame-camera sequences)")
    rng = np.random.default_rng(0)
    floors, actual = [], []
    for k in range(count):
        truth, r = synthetic_run("frame", k, folder)
        if r is None:
            continue
        poses = read_board_poses(folder / f"frame{k}" / "truth.yaml")
        frames = [TargetFrame(f.name, poses[f.name], f.lidar.points, f.lidar.edges, f.lidar.azimuth_step_rad)
                  for f in r.target.used]
        board = r.target.board

        def weighted(x: np.ndarray) -> np.ndarray:
            ext = truth.perturbed(x[:3], x[3:])
            out = []
            for f in frames:
                plane, edge = residuals_at(ext, f, board)
                out.append(plane / f.lidar_rms)
                if len(edge):
                    reach = f.edge_step_rad * np.linalg.norm(f.edges, axis=1)
                    out.append(edge / np.sqrt(reach**2 / 12 + f.lidar_rms**2))
            return np.concatenate(out)

        J = np.column_stack([(weighted(h) - weighted(-h)) / 2e-6 for h in 1e-6 * np.eye(6)])
        sd = np.sqrt(np.diag(np.linalg.inv(J.T @ J)))
        draws = rng.standard_normal((4000, 6)) * sd
        floors.append((1000 * np.median(np.linalg.norm(draws[:, :3], axis=1)),
                       np.degrees(np.median(np.linalg.norm(draws[:, 3:], axis=1)))))
        g, m = truth.error_to(r.extrinsic)
        actual.append((1000 * m, g))
    f, a = np.median(floors, axis=0), np.median(actual, axis=0)
    print(f"   median error the noise allows {f[0]:.2f} mm / {f[1]:.3f} deg; the solver's {a[0]:.2f} mm / {a[1]:.3f} deg "
          f"over {len(actual)} sequences")


def ablation(count: int, folder: Path) -> None:
    """What holds the solve above the information floor, on ``count`` synthetic frame-camera
    sequences: the same lidar boards solved (a) as calibrate does, (b) with the TRUE camera
    boards in place of the detected ones, (c) with other frame-level scales of the three residual
    blocks (board offset m, tilt deg, edges m: solve.FRAME_PLANE_M, FRAME_TILT_DEG, FRAME_EDGE_M);
    median error against the truth (mm / deg)."""
    import importlib
    import itertools

    from l2e_studio.synth.board_dataset import read_board_poses
    from l2e_studio.target import TargetFrame

    S = importlib.import_module("l2e_studio.target.solve")  # the module (the package exports its solve())
    cases = []
    for k in range(count):
        truth, r = synthetic_run("frame", k, folder)
        if r is not None:
            cases.append((truth, r, read_board_poses(folder / f"frame{k}" / "truth.yaml")))
    prior = (S.FRAME_PLANE_M, S.FRAME_TILT_DEG, S.FRAME_EDGE_M)

    def median_error(scales, true_boards: bool) -> str:
        S.FRAME_PLANE_M, S.FRAME_TILT_DEG, S.FRAME_EDGE_M = scales
        try:
            errs = []
            for truth, r, poses in cases:
                frames = [TargetFrame(f.name, poses[f.name] if true_boards else f.detection.pose, f.lidar.points,
                                      f.lidar.edges, f.lidar.azimuth_step_rad) for f in r.target.used]
                g, m = truth.error_to(S.solve(frames, r.target.board, r.extrinsic, covariance=False).extrinsic)
                errs.append((1000 * m, g))
        finally:
            S.FRAME_PLANE_M, S.FRAME_TILT_DEG, S.FRAME_EDGE_M = prior
        e = np.median(np.array(errs), axis=0)
        return f"{e[0]:.2f} mm / {e[1]:.3f} deg"

    print(f"== ablation ({len(cases)} synthetic frame-camera sequences; median error, detected boards | true boards)")
    for scales in [prior] + [s for s in itertools.product((0.03, 0.01, 0.003), (1.5, 0.5, 0.2), (0.01, 0.003)) if s != prior]:
        print(f"   offset {scales[0]:g} m, tilt {scales[1]:g} deg, edges {scales[2]:g} m"
              f"{' (the solve as it is)' if scales == prior else ''}: {median_error(scales, False)} | {median_error(scales, True)}")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--realdata", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "realdata")
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--halves", type=int, default=10)
    ap.add_argument("--synthetic", type=int, default=3, help="synthetic sequences per modality (l2e-studio synth --target)")
    ap.add_argument("--calibration", type=int, default=0,
                    help="synthetic sequences per modality for the sigma calibration (0: skip)")
    ap.add_argument("--floor", type=int, default=0,
                    help="synthetic frame sequences for the information floor (Cramer-Rao; 0: skip)")
    ap.add_argument("--ablation", type=int, default=0,
                    help="synthetic frame sequences for the ablation: detected vs true camera boards, block scales (0: skip)")
    ap.add_argument("--lidars", type=int, default=0,
                    help="synthetic frame sequences per lidar model (vlp16, hdl32, hdl64, os128; 0: skip)")
    ap.add_argument("--synth-dir", type=Path, default=None,
                    help="keep the synthetic sequences here and reuse those already written (default: a temporary folder)")
    ap.add_argument("--sets", default=",".join(SETS), help="comma-separated dev sets (default: all three; '' for none)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.synth_dir or Path(tmp)
        if args.synthetic:
            synthetic(args.synthetic, folder)
        if args.calibration:
            calibration(args.calibration, folder)
        if args.floor:
            information_floor(args.floor, folder)
        if args.ablation:
            ablation(args.ablation, folder)
        if args.lidars:
            lidars(args.lidars, folder)
    results = {}
    for name in filter(None, args.sets.split(",")):
        folder = args.realdata / name
        ss = load_scene_folder(folder, seed_file=folder / "reference.yaml")
        ref, est, board = ss.seed, load_seed(folder / "lcecalib_estimate.yaml"), load_target(folder / "target.yaml")
        # cold: an empty cache folder
        old = os.environ.get("XDG_CACHE_HOME")
        with tempfile.TemporaryDirectory() as tmp:
            os.environ["XDG_CACHE_HOME"] = tmp
            t = time.perf_counter()
            calibrate_target(ss.scenes, ss.camera, ref, board)
            cold = time.perf_counter() - t
            t = time.perf_counter()
            calibrate_target(ss.scenes, ss.camera, ref, board)
            warm = time.perf_counter() - t
        if old is None:
            os.environ.pop("XDG_CACHE_HOME", None)
        else:
            os.environ["XDG_CACHE_HOME"] = old
        dets = detect_frames(ss.scenes, ss.camera, board)
        rate = sum(d.found for d in dets) / len(dets)
        print(f"\n== {name}: {len(ss.scenes)} frames, board detected in {100 * rate:.0f} %  "
              f"({', '.join(sorted({d.method for d in dets if d.found}))}); missed: "
              f"{[d.name for d in dets if not d.found]}")
        print(f"   time for all {len(ss.scenes)} frames incl. detection: cold {cold:.2f} s, cached {warm:.2f} s")
        rng = np.random.default_rng(0)
        all_ends = []
        for deg, m in ((2.0, 0.10), (5.0, 0.20)):
            ends, trusted = [], 0
            for _ in range(args.runs):
                r = calibrate_target(ss.scenes, ss.camera, offset_seed(ref, deg, m, rng), board, detections=dets)
                ends.append(r.extrinsic)
                trusted += judge_target(r).status == "trusted"
            s_mm, s_deg = spread(ends)
            all_ends += ends
            print(f"   seeds {deg:g} deg / {100 * m:g} cm: spread {s_mm:.2f} mm / {s_deg:.4f} deg, trusted {trusted}/{args.runs}")
        s_mm, s_deg = spread(all_ends)
        print(f"   all {len(all_ends)} seeds: spread {s_mm:.2f} mm / {s_deg:.4f} deg")
        r = calibrate_target(ss.scenes, ss.camera, ref, board, detections=dets)
        v = judge_target(r)
        results[name] = r.extrinsic
        for label, other in (("reference.yaml", ref), ("lcecalib_estimate.yaml", est)):
            g, mm = other.error_to(r.extrinsic)
            print(f"   vs {label}: {100 * mm:.2f} cm / {g:.3f} deg")
        print(f"   verdict {v.status}; sigma x y z {np.round(1000 * r.target.sigma_m, 2)} mm, "
              f"rx ry rz {np.round(r.target.sigma_deg, 3)} deg; board RMS {1000 * r.target.plane_rms_m():.1f} mm, "
              f"edges {1000 * r.target.edge_rms_m():.1f} mm")
        for c in v.checks:
            print(f"     [{'x' if c.passed else ' '}] {c.name}: {c.detail}")
        names = [sc.name for sc in ss.scenes]
        corr, sig = [], []
        for _ in range(args.halves):
            keep = set(rng.choice(names, len(names) // 2, replace=False))
            h = calibrate_target(ss.scenes, ss.camera, ref, board, exclude=set(names) - keep, detections=dets)
            corr.append(correction(r.extrinsic, h.extrinsic))
            sig.append(np.concatenate([1000 * h.target.sigma_m, h.target.sigma_deg]))
        corr, sig = np.array(corr), np.array(sig)
        sd = corr.std(axis=0, ddof=1)
        rep = np.median(sig, axis=0)
        print("   half-splits: spread (std) x y z mm " + " ".join(f"{v:.2f}" for v in sd[:3]) +
              ", rx ry rz deg " + " ".join(f"{v:.3f}" for v in sd[3:]))
        print("                reported sigma / spread " + " ".join(f"{a / b:.2f}" for a, b in zip(rep, sd)))
    if "lcecalib_rles01_frame" in results and "lcecalib_rles01_event" in results:
        g, m = results["lcecalib_rles01_frame"].error_to(results["lcecalib_rles01_event"])
        print(f"\nrles01 frame vs event: {100 * m:.2f} cm / {g:.3f} deg (LCE-Calib's own: 2.8-4.0 cm / 0.6-1.2 deg)")


if __name__ == "__main__":
    main()
