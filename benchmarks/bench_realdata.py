"""Real dev rigs (../shared/realdata): closer / kept / worse than the seed, old engine vs new.

Per rig and seed level (1 deg / 5 cm, 2 deg / 10 cm, 5 deg / 20 cm; random axis and direction,
fixed RNG), calibrate from reference-perturbed seeds with
* ``mi``: the paper's MI, no verdict (the tool before the structure-aware objective), and
* ``new``: the default (objective chosen from the map kind, multi-start, verdict), and
* ``scan``: the same with the edge maps reading the gradient across the scan lines only
  (``edge_gradient="scan-lines"``).
A run is *worse* when its rotation error grows by > 0.1 deg or its translation error by > 1 cm,
*closer* when it is not worse and one of them shrinks by more than that, else *kept*.
Also: runs started at the reference, and one-axis sweeps of the new objective (PNG).

    python benchmarks/bench_realdata.py [--runs 20] [--rigs all|none|manual,1+2,3,kitti,<folder>...] [--sweeps]
        [--levels 1,2,5,0] [--synthetic vlp16,hdl32,hdl64,os128 [--synthetic-scenes 1,8] [--revolutions 3
        [--phase-locked]]] [--save rows.json]
    python benchmarks/bench_realdata.py --rigs 1+2,kitti_odometry_00 --split 1  # every scan a rig of its own
    python benchmarks/bench_realdata.py --rigs kitti_odometry_00 --sparse 2 1   # its drive as 16- and 32-beam lidars see it
    python benchmarks/bench_realdata.py --rigs kitti_odometry_00 --sparse 2 --width 346  # ... and a DAVIS346-sized camera
    python benchmarks/bench_realdata.py --rigs kitti_odometry_00 --sparse 2 --crop 34    # ... or a lens as narrow as HITSZ's
    python benchmarks/bench_realdata.py --table old.json new.json     # two saved runs side by side
    python benchmarks/bench_realdata.py --nudge 1e-4 --save nudged.json  # every seed turned 1e-4 deg more
    python benchmarks/bench_realdata.py --flips plain.json nudged.json   # run by run: verdicts that flipped

``--nudge`` measures how much of a verdict is chance: a seed turned by a ten-thousandth of a
degree is the same seed to any sensor, so a verdict that flips under it was decided by noise
(stop 34: a float64 objective, equally exact, flipped 30 of 310).

The engine is whatever ``l2e_studio`` imports: run once with ``PYTHONPATH`` at a checkout of an
older commit (``git worktree add /tmp/l2e_old <commit>``) and ``--save old.json``, once here with
``--save new.json``, then ``--table`` the two.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from realdata_rigs import cropped, load_rigs, perturbations, resized, sparse, split, synthetic_rigs  # noqa: E402

from l2e_studio.calibrate import CalibrationSettings, calibrate, stack_scenes  # noqa: E402
from l2e_studio.verdict import judge  # noqa: E402

LEVELS = {1: (1.0, 0.05), 2: (2.0, 0.10), 5: (5.0, 0.20), 0: (0.0, 0.0)}
#: the engines compared: the paper's MI without a verdict, the default engine, and the default
#: with the edge maps reading the gradient across the scan lines only
VARIANTS = {"mi": CalibrationSettings(objective="mi", global_search=False), "new": CalibrationSettings(),
            "scan": CalibrationSettings(edge_gradient="scan-lines")}
OUT = Path(__file__).resolve().parent / "out"


def classify(seed_err: tuple[float, float], end_err: tuple[float, float]) -> str:
    dr, dt = end_err[0] - seed_err[0], end_err[1] - seed_err[1]
    if dr > 0.1 or dt > 0.01:
        return "worse"
    return "closer" if dr < -0.1 or dt < -0.01 else "kept"


def board_evidence(rig):
    """For a rig with a checkerboard in view: ``check(verdict, seed) -> verdict`` adding the
    boards' agreement with what the verdict hands back (target_verdict.with_boards); else None."""
    if rig.board is None:
        return None
    from l2e_studio.target import detect_frames, load_target
    from l2e_studio.target_verdict import with_boards

    board = load_target(rig.board)
    found = detect_frames(rig.scenes, rig.camera, board, use_cache=False)
    return lambda v, seed: with_boards(v, seed, rig.scenes, rig.camera, board, detections=found)


def host() -> str:
    """The CPU and the numeric kernels numpy and OpenBLAS chose on it: a climb's rounding,
    and with it about one verdict in ten on a single scan, follows them (stop 36: the same
    commit on two hosts flipped 27 of 310 verdicts), so saved rows say where they ran."""
    import platform

    from threadpoolctl import threadpool_info

    try:
        cpu = next(line.split(":", 1)[1].strip() for line in open("/proc/cpuinfo") if line.startswith("model name"))
    except (OSError, StopIteration):
        cpu = platform.processor() or platform.machine()
    # sorted: the order is the order the libraries were loaded in, which is no property of the host
    blas = ", ".join(sorted({f"{i['internal_api']} {i.get('architecture', '')}".strip()
                             for i in threadpool_info() if i["user_api"] == "blas"}))
    try:
        from numpy._core._multiarray_umath import __cpu_features__ as features
    except ImportError:  # numpy < 2
        features = {}
    simd = next((k for k in ("AVX512_SKX", "AVX512F", "AVX2", "NEON", "SSE42") if features.get(k)), "baseline")
    return f"{cpu}; {blas or 'no BLAS'}; numpy {simd}"


def nudged(seed, run: int, nudge_deg: float):
    """``seed`` turned ``nudge_deg`` more about an axis fixed by the run's index (the same in
    every invocation), or ``seed`` itself."""
    if not nudge_deg:
        return seed
    axis = np.random.default_rng(7000 + run).normal(size=3)
    return seed.perturbed(np.zeros(3), np.radians(nudge_deg) * axis / np.linalg.norm(axis))


def run_rig(rig, runs: int, levels, variants, boards: bool = False, nudge_deg: float = 0.0,
            details: bool = False) -> list[dict]:
    rows = []
    with_boards = board_evidence(rig) if boards and set(variants) - {"mi"} else None
    for variant in variants:
        settings = VARIANTS[variant]
        judged = variant != "mi"  # every engine but the paper's MI has a verdict
        stack = stack_scenes(rig.scenes, rig.camera, rig.reference,
                             replace(settings, translation_bound=0.5, rotation_bound_deg=20.0))
        for deg, m in levels:
            li = list(LEVELS.values()).index((deg, m))  # the same seeds whichever levels run
            starts = perturbations(runs, deg, m, 1000 + li) if deg > 0 else [(np.zeros(3), np.zeros(3))] * 2
            for k, (dt, dr) in enumerate(starts):
                seed = nudged(rig.reference.perturbed(dt, dr), k, nudge_deg)
                t0 = time.perf_counter()
                aimed = stack.aimed_at(seed)  # edge maps read as the seed (not the reference) projects the scan lines
                result = calibrate(aimed, None, seed, settings)
                status, end = "-", result.extrinsic
                if judged:
                    v = judge(aimed, result, settings)
                    if with_boards is not None:
                        v = with_boards(v, seed)
                    status, end = v.status, v.extrinsic
                seconds = time.perf_counter() - t0
                se, ee = seed.error_to(rig.reference), end.error_to(rig.reference)
                unpinned = [a.axis for a in getattr(v, "translation", ()) if not a.pinned] if judged else []
                spread = getattr(v, "spread", None) if judged else None
                oe, move = result.extrinsic.error_to(rig.reference), seed.error_to(result.extrinsic)
                rows.append(dict(rig=rig.name, variant=variant, unpinned="".join(unpinned), level=f"{deg:g}deg/{100 * m:g}cm", seed_deg=se[0], seed_m=se[1],
                                 end_deg=ee[0], end_m=ee[1], cls=classify(se, ee), status=status, seconds=seconds,
                                 opt_deg=oe[0], opt_m=oe[1], move_deg=move[0], move_m=move[1],
                                 spread_deg=None if spread is None else spread.deg,
                                 spread_m=None if spread is None or np.isnan(spread.m) else spread.m,
                                 settled=getattr(v, "settled", "") if judged else "",
                                 # for studying the verdict's rules offline: each check's outcome, each
                                 # axis's probe drop, and the optimiser's translation error per camera axis
                                 checks={c.name: c.passed for c in v.checks} if judged else {},
                                 details={c.name: c.detail for c in v.checks} if judged and details else {},
                                 drops=[a.drop for a in v.translation] if judged else [],
                                 opt_dt=(result.extrinsic.translation - rig.reference.translation).tolist(),
                                 # the poses themselves (rotation vector, then translation), for scoring offline
                                 poses={k: [*x.rotvec.tolist(), *x.translation.tolist()]
                                        for k, x in (("seed", seed), ("result", result.extrinsic), ("end", end))}))
                print(f"{rig.name:6s} {variant} {rows[-1]['level']:11s} {se[0]:.2f}/{100 * se[1]:.1f} -> "
                      f"{ee[0]:.2f}/{100 * ee[1]:.1f} {rows[-1]['cls']:6s} {status:16s} {seconds:.1f}s "
                      f"(optimiser {oe[0]:.2f}/{100 * oe[1]:.1f})", flush=True)
    return rows


def trusted_but_worse(rows) -> int:
    """How many of ``rows`` hand back a result judged trusted (whole or its rotation) that is
    worse than its seed: the defect the verdict must never commit."""
    return sum(r["status"] not in ("not-trusted", "-") and r["cls"] == "worse" for r in rows)


def table(rows: list[dict], label: str = "") -> str:
    """One line per rig, seed level and variant: closer / kept / worse, median end error, statuses."""
    lines = ["| rig | seeds | engine | closer | kept | worse | median end error | trusted / rot. only / not | trusted but worse |",
             "|---|---|---|---|---|---|---|---|---|"]
    def key(r: dict) -> tuple:
        return r["rig"], r["level"], r["variant"], r.get("engine", label)

    order = [list(dict.fromkeys(k[i] for k in map(key, rows))) for i in range(4)]
    keys = sorted(set(map(key, rows)), key=lambda k: tuple(order[i].index(k[i]) for i in range(4)))
    for rig, level, variant, engine in keys:
        sel = [r for r in rows if key(r) == (rig, level, variant, engine)]
        c = {k: sum(r["cls"] == k for r in sel) for k in ("closer", "kept", "worse")}
        med = f"{np.median([r['end_deg'] for r in sel]):.2f} deg / {100 * np.median([r['end_m'] for r in sel]):.1f} cm"
        trusted_worse = "-"
        st = "-"
        if variant != "mi":
            st = "/".join(str(sum(r["status"] == s for r in sel)) for s in ("trusted", "trusted-rotation", "not-trusted"))
            trusted_worse = str(trusted_but_worse(sel))
        name = "paper MI, no verdict" if variant == "mi" else (engine or {"new": "auto + verdict"}.get(variant, variant))
        lines.append(f"| {rig} | {level} | {name} | {c['closer']} | {c['kept']} | {c['worse']} | {med} | {st} | {trusted_worse} |")
    return "\n".join(lines)


def flips(a: list[dict], b: list[dict]) -> str:
    """Two saved runs of the same seeds, run by run: per rig and level, the verdicts that
    differ, how many of those at the same optimiser end (within 0.05 deg / 5 mm: a probe of the
    verdict's own came out the other way), and trusted-but-worse in each."""
    def group(rows):
        g: dict = {}
        for r in rows:
            g.setdefault((r["rig"], r["level"], r["variant"]), []).append(r)
        return g

    ga, gb = group(a), group(b)
    lines = ["| rig | seeds | runs | verdicts flipped | of them at the same optimiser end | trusted but worse, a / b |",
             "|---|---|---|---|---|---|"]
    total = [0, 0, 0]
    for key in ga:
        pairs = list(zip(ga[key], gb.get(key, [])))
        flipped = [(x, y) for x, y in pairs if x["status"] != y["status"]]
        same = sum(abs(x["opt_deg"] - y["opt_deg"]) <= 0.05 and abs(x["opt_m"] - y["opt_m"]) <= 0.005 for x, y in flipped)
        tw_a, tw_b = trusted_but_worse(x for x, _ in pairs), trusted_but_worse(y for _, y in pairs)
        total = [total[0] + len(pairs), total[1] + len(flipped), total[2] + same]
        lines.append(f"| {key[0]} | {key[1]} | {len(pairs)} | {len(flipped)} | {same} | {tw_a} / {tw_b} |")
    lines.append(f"| all | | {total[0]} | {total[1]} | {total[2]} | |")
    hosts = [{r.get("host", "not recorded") for r in rows} for rows in (a, b)]
    if hosts[0] != hosts[1]:
        lines.append(f"\nran on different hosts (a: {', '.join(sorted(hosts[0]))}; b: {', '.join(sorted(hosts[1]))}): "
                     "their rounding alone flips verdicts")
    return "\n".join(lines)


def sweeps(rigs, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    axes = ("x (m)", "y (m)", "z (m)", "rot x (deg)", "rot y (deg)", "rot z (deg)")
    fig, grid = plt.subplots(len(rigs), 6, figsize=(18, 2.6 * len(rigs)), squeeze=False)
    for i, rig in enumerate(rigs):
        stack = stack_scenes(rig.scenes, rig.camera, rig.reference, CalibrationSettings(translation_bound=0.5, rotation_bound_deg=20.0))
        final = stack.with_sigma(CalibrationSettings().sigma)
        for k in range(6):
            steps = np.linspace(-0.3, 0.3, 41) if k < 3 else np.linspace(-3.0, 3.0, 41)
            vals = []
            for s in steps:
                d = np.zeros(6)
                d[k] = s if k < 3 else np.radians(s)
                vals.append(final.score(rig.reference.perturbed(d[:3], d[3:]), per_scene=False)[0])
            ax = grid[i, k]
            ax.plot(steps, vals)
            ax.axvline(0.0, color="k", lw=0.8)
            peak = steps[int(np.argmax(vals))]
            ax.set_title(f"{rig.name}: peak at {peak:+.3g}", fontsize=9)
            ax.set_xlabel(axes[k], fontsize=8)
            print(f"sweep {rig.name:6s} {axes[k]:12s} peak at {peak:+.3f}", flush=True)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--runs", type=int, default=20, help="runs per rig and seed level (0: none, e.g. with --sweeps)")
    p.add_argument("--rigs", default="all")
    p.add_argument("--levels", default="1,2,5,0", help="seed levels: 1 (1 deg / 5 cm), 2, 5, 0 (the reference)")
    p.add_argument("--variants", default="mi,new", help=f"engines: {', '.join(VARIANTS)}")
    p.add_argument("--sweeps", action="store_true")
    p.add_argument("--boards", action="store_true",
                   help="rigs with a target.yaml: the boards in view must agree with a trusted result")
    p.add_argument("--synthetic", help="also synthetic rigs (a known truth: an unseen rig's stand-in): spinning "
                                       "lidars, e.g. vlp16,hdl64 (--rigs none: those alone)")
    p.add_argument("--synthetic-scenes", default="1,8", help="scenes per synthetic rig, e.g. 1,8")
    p.add_argument("--revolutions", type=int, default=1,
                   help="synthetic rigs: revolutions accumulated into each scene's cloud, as a static rig records")
    p.add_argument("--phase-locked", action="store_true",
                   help="... each at the same azimuths (a phase-locked lidar), not interleaved")
    p.add_argument("--split", type=int, default=0,
                   help="every K consecutive scenes of the rigs a rig of their own (1: every scan alone)")
    p.add_argument("--sparse", type=float, nargs="+",
                   help="the rigs' scans thinned to rings this many degrees apart (e.g. 2: a 64-beam drive as a "
                        "16-beam lidar would see it), each spacing a rig of its own")
    p.add_argument("--width", type=int, nargs="+",
                   help="the rigs' images (and cameras) resized to this many pixels across (e.g. 346: a DAVIS346's), "
                        "each width a rig of its own")
    p.add_argument("--crop", type=float, nargs="+",
                   help="the rigs' images cut to the central this many degrees across (e.g. 34: HITSZ's narrow "
                        "lens), each a rig of its own")
    p.add_argument("--save", type=Path, help="write every run's row here (JSON)")
    p.add_argument("--table", type=Path, nargs="+", help="saved runs to tabulate side by side (no calibration)")
    p.add_argument("--nudge", type=float, default=0.0, help="turn every seed this many degrees more (a fixed axis per run)")
    p.add_argument("--details", action="store_true", help="keep each check's words in the rows (its numbers, for study)")
    p.add_argument("--flips", type=Path, nargs=2, help="two saved runs of the same seeds: verdicts that differ, run by run")
    args = p.parse_args()
    if args.flips:
        print(flips(*(json.loads(path.read_text()) for path in args.flips)))
        return
    if args.table:
        rows = []
        for path in args.table:
            rows += [dict(r, engine=path.stem) for r in json.loads(path.read_text())]
        print(table(rows))
        return
    rigs = load_rigs(args.rigs.split(",")) if args.rigs != "none" else []
    if args.synthetic:
        rigs += synthetic_rigs(args.synthetic.split(","), [int(k) for k in args.synthetic_scenes.split(",")],
                               revolutions=args.revolutions, phase_locked=args.phase_locked)
    if args.split:
        rigs = split(rigs, args.split)
    if args.sparse:
        rigs = [r for deg in args.sparse for r in sparse(rigs, deg)]
    if args.width:
        rigs = [r for w in args.width for r in resized(rigs, w)]
    if args.crop:
        rigs = [r for deg in args.crop for r in cropped(rigs, deg)]
    if not rigs:
        sys.exit("no real data found under ../shared/realdata (set L2E_REALDATA)")
    if args.sweeps:
        sweeps(rigs, OUT / "realdata_sweeps.png")
    levels = [LEVELS[int(k)] for k in args.levels.split(",")] if args.runs > 0 else []  # --runs 0: sweeps only
    rows, where = [], host()
    for rig in rigs if levels else ():
        rows += [dict(r, host=where) for r in run_rig(rig, args.runs, levels, args.variants.split(","), args.boards,
                                                      args.nudge, args.details)]
        if args.save:
            args.save.write_text(json.dumps(rows))  # compact, as the rows kept in results/
    print(table(rows))


if __name__ == "__main__":
    main()
