"""Information scores of lidar intensity against grey, beside the edge score (issue 16, stop 40).

The issue names "a normalised information distance on intensities" among the candidates for
sparse rigs. Stop 30 measured it only as a landscape around each reference; this study also
climbs it. Scores (higher is better for all, so each is climbed the same way):

* ``edges``: the engine's edge score (the default objective for camera images);
* ``nid``: minus the normalised information distance ``1 - I(L; E) / H(L, E)`` of lidar
  intensity L and the grey level E the point lands on, all scenes' pairs pooled;
* ``nid_mean``: minus the same per scene, averaged (every scene weighted alike).

Both information scores use the paper's MI machinery (256 x 256 joint histogram, Silverman
smoothing, :mod:`l2e_studio.scoring.mi`) on a stack of every lidar point that can reach the image.

Two measurements per rig:

1. *Landscape*: the share of 24 random rotations 0.25 / 0.5 / 1 / 2 / 5 deg off the reference,
   and of 24 random translations 2 / 5 / 10 cm off, that score at least the reference's value
   (0 everywhere: the score peaks at the reference, as far as these poses see).
2. *Climb*: the rotation alone (translation held at the seed's) climbed by Nelder-Mead, coarse
   to fine (maps smoothed 8, 4, 2 px; first simplexes 1, 0.5, 0.25 deg), from ``--seeds``
   seeds 2 deg / 10 cm off the reference: the end's rotation error, and the end's score against
   the reference's. The same climber for every score, so the scores are compared, not the
   engine's search.

    L2E_REALDATA=../shared/realdata python benchmarks/study_nid.py --rigs hitsz_vlp16,lcecalib_rlfs01
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import cv2
import numpy as np
from scipy.optimize import minimize

from l2e_studio.calibrate import CalibrationSettings, stack_scenes
from l2e_studio.objective.stack import SceneStack
from l2e_studio.scoring.mi import N_BINS, entropy, kernel_taps, silverman_bandwidth, weighted_std
from realdata_rigs import load_rigs, perturbations

SCORES = ("edges", "nid", "nid_mean")
ANGLES_DEG = (0.25, 0.5, 1.0, 2.0, 5.0)
SHIFTS_M = (0.02, 0.05, 0.10)
STAGES_PX = (8.0, 4.0, 2.0)
SIMPLEX_DEG = (1.0, 0.5, 0.25)  # a local climb: the first simplex's size per stage
MIN_PAIRS = 100  # a scene with fewer pairs in view has no NID of its own


def nid(counts: np.ndarray) -> float:
    """The normalised information distance of a (256, 256) joint count histogram, smoothed as
    the paper's MI smooths it (Silverman widths from its own marginals)."""
    counts = counts.reshape(N_BINS, N_BINS).astype(np.float64)
    n = counts.sum()
    h_l = silverman_bandwidth(weighted_std(counts.sum(axis=1)), int(n))
    h_e = silverman_bandwidth(weighted_std(counts.sum(axis=0)), int(n))
    p = cv2.sepFilter2D((counts / n).astype(np.float32), -1, kernel_taps(float(h_e), "float32"),
                        kernel_taps(float(h_l), "float32"), borderType=cv2.BORDER_REFLECT)
    joint = entropy(p)
    mi = entropy(p.sum(axis=1)) + entropy(p.sum(axis=0)) - joint
    return 1.0 - mi / joint


class Scores:
    """The three scores of one rig at any extrinsic, at one smoothing of the maps."""

    def __init__(self, rig, sigma: float, stacks: tuple | None = None):
        if stacks is None:
            info = SceneStack.build(rig.scenes, rig.camera, 0.0, rig.reference, 0.5, 20.0, objective="mi")
            settings = replace(CalibrationSettings(), translation_bound=0.5, rotation_bound_deg=20.0)
            stacks = (info, stack_scenes(rig.scenes, rig.camera, rig.reference, settings))
        self.stacks = stacks
        self.info, self.edges = stacks[0].with_sigma(sigma), stacks[1].with_sigma(sigma)

    def at(self, extrinsic, which: str) -> float:
        if which == "edges":
            return float(self.edges.score(extrinsic, per_scene=False)[0])
        joints = self.info.joint_histograms(extrinsic).reshape(self.info.n_scenes, -1)
        if which == "nid":
            return -nid(joints.sum(axis=0))
        return -float(np.mean([nid(j) for j in joints if j.sum() >= MIN_PAIRS]))


def rotation_error_deg(a, b) -> float:
    c = (np.trace(a.R @ b.R.T) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def landscape(scores: Scores, rig, directions: np.ndarray) -> dict[str, list[float]]:
    """Per score: the shares of rotations (ANGLES_DEG) and translations (SHIFTS_M) scoring >= the reference."""
    out = {}
    for which in SCORES:
        at_ref = scores.at(rig.reference, which)
        rot = [np.mean([scores.at(rig.reference.perturbed(np.zeros(3), np.radians(a) * d), which) >= at_ref
                        for d in directions]) for a in ANGLES_DEG]
        move = [np.mean([scores.at(rig.reference.perturbed(m * d, np.zeros(3)), which) >= at_ref
                         for d in directions]) for m in SHIFTS_M]
        out[which] = [float(x) for x in rot + move]
    return out


def climb(stages: list[Scores], seed, which: str):
    """The rotation climbed from ``seed`` through ``stages`` (Nelder-Mead in degrees); the end."""
    current = seed
    for scores, size in zip(stages, SIMPLEX_DEG):
        def f(x, start=current):
            return -scores.at(start.perturbed(np.zeros(3), np.radians(x)), which)
        simplex = np.vstack([np.zeros(3), size * np.eye(3)])
        r = minimize(f, np.zeros(3), method="Nelder-Mead",
                     options=dict(initial_simplex=simplex, xatol=1e-3, fatol=1e-9, maxfev=300))
        current = current.perturbed(np.zeros(3), np.radians(r.x))
    return current


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rigs", default="manual,1+2,kitti_odometry_00,hitsz_vlp16,lcecalib_rlfs01,lcecalib_rles01_frame")
    p.add_argument("--seeds", type=int, default=4, help="climbs per rig and score (2 deg / 10 cm seeds)")
    p.add_argument("--no-climb", action="store_true")
    args = p.parse_args()
    d = np.random.default_rng(7).normal(size=(24, 3))
    directions = d / np.linalg.norm(d, axis=1)[:, None]
    for rig in load_rigs(args.rigs.split(",")):
        t0 = time.time()
        final = Scores(rig, STAGES_PX[-1])
        print(f"## {rig.name} ({len(rig.scenes)} scenes)")
        print("| score | rotation " + " / ".join(f"{a:g}" for a in ANGLES_DEG) + " deg | translation "
              + " / ".join(f"{100 * m:g}" for m in SHIFTS_M) + " cm |")
        for which, shares in landscape(final, rig, directions).items():
            rot, move = shares[:len(ANGLES_DEG)], shares[len(ANGLES_DEG):]
            print(f"| {which} | " + " / ".join(f"{s:.2f}" for s in rot) + " | " + " / ".join(f"{s:.2f}" for s in move) + " |")
        if not args.no_climb:
            stages = [Scores(rig, s, final.stacks) for s in STAGES_PX[:-1]] + [final]
            seeds = [rig.reference.perturbed(dt, dr) for dt, dr in perturbations(args.seeds, 2.0, 0.10, 1002)]
            for which in SCORES:
                ends = [climb(stages, seed, which) for seed in seeds]
                errs = [rotation_error_deg(e, rig.reference) for e in ends]
                above = sum(final.at(e, which) > final.at(rig.reference, which) for e in ends)
                print(f"- climb `{which}` from {len(seeds)} seeds 2 deg / 10 cm: rotation error "
                      + ", ".join(f"{e:.2f}" for e in errs) + f" deg (median {np.median(errs):.2f});"
                      f" {above} of {len(ends)} ends score above the reference")
        print(f"({time.time() - t0:.0f} s)\n", flush=True)


if __name__ == "__main__":
    main()
