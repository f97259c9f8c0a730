"""How far a result's score rises above its seed's, against the landscape's own fluctuation (stop 41).

A bias every scene shares passes the verdict's consistency checks (the halves, the second start
land where the result did). What it cannot fake is a score that rises clearly above the seed's.
This study reads saved ``bench_realdata.py`` rows (their seeds and results), scores both again
on the stack the verdict judges (the final smoothing, at most ``peaks.FAR_POINTS`` points) and
expresses the difference in standard deviations of the far field 2-8 deg around the result, its
trend taken out (the significance check's measure, :func:`l2e_studio.peaks.significance`):

* ``rise``: the whole result above the seed;
* ``axes``: the part of the move about each camera axis (x right, y down, z forward) undone, one
  at a time: what each axis's part of the turn adds;
* ``--translation``: for trusted rows, each translation axis handed back set to the seed's;
* ``--turn DEG``: the share of its score the result loses turned DEG about each camera axis (the
  smaller side), as the verdict's translation probes measure a move.

It prints one line per row and, per rig, the rows trusted and closer with the lowest rise and
every trusted row under ``--below`` deviations.

    L2E_REALDATA=../shared/realdata python benchmarks/study_rise.py \\
        benchmarks/results/realdata_stop40.json benchmarks/results/realdata_stop40_sparse_narrow.json
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from l2e_studio.calibrate import CalibrationSettings, stack_scenes
from l2e_studio.geometry import Extrinsic
from l2e_studio.peaks import FAR_POINTS, significance
from realdata_rigs import ALL, cropped, load_rigs, resized, sparse, split


def rig_named(name: str, base: dict):
    """The rig ``name`` as bench_realdata.py names its derived rigs (``<rig>/<scene>``, ``~2deg``,
    ``@604px``, ``|34deg``, applied in that order), or None where its data are absent."""
    stem = name.split("/")[0].split("~")[0].split("@")[0].split("|")[0]
    if stem not in base:
        return None
    rigs = [base[stem]]
    if "/" in name:
        rigs = split(rigs, 1)
    if "~" in name:
        rigs = sparse(rigs, float(name.split("~")[1].split("deg")[0]))
    if "@" in name:
        rigs = resized(rigs, int(name.split("@")[1].split("px")[0]))
    if "|" in name:
        rigs = cropped(rigs, float(name.split("|")[1].split("deg")[0]))
    return next((r for r in rigs if r.name == name), None)


def pose(values: list[float]) -> Extrinsic:
    return Extrinsic(np.array(values[:3]), np.array(values[3:]))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("rows", type=Path, nargs="+", help="saved bench_realdata.py rows (JSON)")
    p.add_argument("--below", type=float, default=2.0, help="list trusted rows rising less than this")
    p.add_argument("--translation", action="store_true", help="also each handed-back translation axis")
    p.add_argument("--turn", type=float, default=0.0, help="also the score's drop turned this many deg about each axis")
    args = p.parse_args()
    settings = CalibrationSettings()
    base = {r.name: r for r in load_rigs(list(ALL))}
    stacks: dict = {}
    out = []
    for path in args.rows:
        for row in json.loads(path.read_text()):
            if row["variant"] == "mi" or "poses" not in row:
                continue
            rig = rig_named(row["rig"], base)
            if rig is None:
                continue
            if rig.name not in stacks:  # one rig's stack at a time (the rows come rig by rig)
                stacks = {rig.name: stack_scenes(rig.scenes, rig.camera, rig.reference,
                                                 replace(settings, translation_bound=0.5, rotation_bound_deg=20.0))}
            seed, res, end = (pose(row["poses"][k]) for k in ("seed", "result", "end"))
            final = stacks[rig.name].aimed_at(seed).with_sigma(settings.sigma)
            peak = significance(final, res, settings, seed)
            thin = final.thinned(FAR_POINTS)
            turn = (Rotation.from_rotvec(res.rotvec) * Rotation.from_rotvec(seed.rotvec).inv()).as_rotvec()
            undone = [res.perturbed(np.zeros(3), -turn[k] * np.eye(3)[k]) for k in range(3)]
            at = thin.score(res, per_scene=False)[0]
            axes = (at - thin.scores(undone)) / peak.noise
            line = dict(rig=row["rig"], level=row["level"], status=row["status"], cls=row["cls"],
                        end_deg=row["end_deg"], rise=peak.rise, axes=axes.tolist())
            if args.translation and row["status"] != "not-trusted":
                back = [Extrinsic(end.rotvec, np.where(np.arange(3) == k, seed.translation, end.translation))
                        for k in range(3)]
                line["translation"] = ((thin.score(end, per_scene=False)[0] - thin.scores(back)) / peak.noise).tolist()
                ref = rig.reference.translation  # per axis taken from the data: what it gained over the seed (m)
                line["taken"] = [(k, float(abs(seed.translation[k] - ref[k]) - abs(end.translation[k] - ref[k])))
                                 for k in range(3) if end.translation[k] != seed.translation[k]]
            if args.turn:
                turned = thin.scores([res.perturbed(np.zeros(3), sign * np.radians(args.turn) * np.eye(3)[k])
                                      for k in range(3) for sign in (-1.0, 1.0)])
                line["drops"] = ((at - turned.reshape(3, 2).max(axis=1)) / abs(at)).tolist()
            out.append(line)
            print(f"{row['rig']:30s} {row['level']:9s} {row['status']:16s} {row['cls']:6s} end {row['end_deg']:.2f} deg: "
                  f"rise {peak.rise:.1f}, per axis " + " / ".join(f"{a:.1f}" for a in axes)
                  + ("" if "translation" not in line else ", translation " + " / ".join(f"{a:.1f}" for a in line["translation"]))
                  + ("" if "drops" not in line else f", turned {args.turn:g} deg loses "
                     + " / ".join(f"{100 * d:.0f} %" for d in line["drops"])),
                  flush=True)
    print()
    for rig in dict.fromkeys(r["rig"] for r in out):
        mine = [r for r in out if r["rig"] == rig]
        good = [r["rise"] for r in mine if r["status"] != "not-trusted" and r["cls"] == "closer"]
        low = [f"{r['level']} {r['status']} {r['cls']} {r['rise']:.1f}" for r in mine
               if r["status"] != "not-trusted" and r["rise"] < args.below]
        drops = np.array([r["drops"] for r in mine if "drops" in r])
        taken = [(r["translation"][k], gain) for r in mine for k, gain in r.get("taken", ())]
        under = [gain for rise, gain in taken if rise < args.below]
        if taken:
            print(f"{rig}: translation axes taken from the data {len(taken)}, rising under {args.below:g} when set back "
                  f"to the seed's {len(under)}" + (f" (what they gained over the seed: {100 * sum(under):.1f} cm in all, "
                                                   f"{100 * min(under):+.1f} to {100 * max(under):+.1f} cm each)" if under else ""))
        print(f"{rig}: trusted and closer {len(good)}" + (f", lowest rise {min(good):.1f}" if good else "")
              + (f"; trusted under {args.below:g}: " + ", ".join(low) if low else "")
              + ("" if not len(drops) else "; turned, the score loses (min-max per axis) " + ", ".join(
                  f"{100 * lo:.0f}-{100 * hi:.0f} %" for lo, hi in zip(drops.min(axis=0), drops.max(axis=0)))))


if __name__ == "__main__":
    main()
