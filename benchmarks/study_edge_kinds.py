"""The lidar side of the edge score, one kind of edge at a time (issue 16, stop 32).

A lidar point's edge weight is the larger of its depth discontinuity and its intensity step
(:func:`l2e_studio.scoring.edges.lidar_edge_weights`). This study scores each kind alone against
both, at each dev rig's reference: the share of 24 random rotations 0.5 / 1 / 2 / 5 deg off the
reference that score at least as high as the reference (0 everywhere: the score peaks there).

    python benchmarks/study_edge_kinds.py --rigs hitsz_vlp16,lcecalib_rles01_frame,1+2,manual

* ``both``: the engine as it is;
* ``depth``: every intensity set alike (no intensity step anywhere);
* ``intensity``: every point put at 10 m along its own ray (no depth jump anywhere).

The variants swap the weight function the stack is built with (a study, not an engine option:
neither kind alone peaks at the reference where both do not, benchmarks/results/realdata.md).
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

import l2e_studio.objective.stack as stack_module
from l2e_studio.calibrate import CalibrationSettings, stack_scenes
from realdata_rigs import load_rigs

ENGINE = stack_module.lidar_edge_weights
KINDS = ("both", "depth", "intensity")
ANGLES_DEG = (0.5, 1.0, 2.0, 5.0)


def weights_of(kind: str):
    """The lidar edge weight function of one ``kind``."""
    def depth_only(points, intensity):
        return ENGINE(points, np.zeros(len(points), np.float32))

    def intensity_only(points, intensity):
        P = np.asarray(points, np.float64)
        r = np.linalg.norm(P, axis=1, keepdims=True)
        return ENGINE(P / np.where(r > 0, r, 1.0) * 10.0, intensity)

    return {"both": ENGINE, "depth": depth_only, "intensity": intensity_only}[kind]


def shares(rig, weights, directions: np.ndarray, scenes=None) -> list[float]:
    """Per angle of ANGLES_DEG, the share of ``directions`` there that score >= the reference,
    the stack built with the lidar edge weight function ``weights`` from ``scenes`` (default:
    the rig's own)."""
    stack_module.lidar_edge_weights = weights
    try:
        settings = replace(CalibrationSettings(), translation_bound=0.5, rotation_bound_deg=20.0)
        st = stack_scenes(rig.scenes if scenes is None else scenes, rig.camera, rig.reference, settings).with_sigma(2.0)
    finally:
        stack_module.lidar_edge_weights = ENGINE
    at_ref = st.score(rig.reference, per_scene=False)[0]
    return [float(np.mean([st.score(rig.reference.perturbed(np.zeros(3), np.radians(deg) * d), per_scene=False)[0]
                           >= at_ref for d in directions])) for deg in ANGLES_DEG]


def random_directions(n: int = 24) -> np.ndarray:
    """``n`` unit rotation axes, the same every run."""
    d = np.random.default_rng(7).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1)[:, None]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rigs", default="manual,1+2,kitti_odometry_00,hitsz_vlp16,lcecalib_rlfs01,lcecalib_rles01_frame")
    args = p.parse_args()
    directions = random_directions()
    print("| rig | " + " | ".join(KINDS) + " |\n|---|" + "---|" * len(KINDS))
    for rig in load_rigs(args.rigs.split(",")):
        cells = [" / ".join(f"{s:.2f}" for s in shares(rig, weights_of(kind), directions)) for kind in KINDS]
        print(f"| {rig.name} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
