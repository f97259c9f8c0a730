"""Image-side edge maps for the edge score, side by side (issue 16): where the optimiser ends.

The edge score reads a band-passed image gradient under the lidar's edge points. This benchmark
swaps only the gradient step (``scoring.edges.scan_gradient``) for each candidate and, per
rig, runs the optimiser alone (no verdict) from the reference and from ``--seeds`` starts
2 deg / 10 cm off it. It reports each end's error to the reference (on synthetic rigs: the
truth), the score at the end over the score at the reference, and on rigs with a checkerboard
in view the error to the board solve (an independent reference of the same rig).

Candidates (each normalised by its 99th percentile, as the engine's map is):

* ``base``   the engine's default: Sobel magnitude after a 1 px blur;
* ``blur2``  the same after a 2 px blur (fine texture suppressed);
* ``gx``     the engine's ``edge_gradient="scan-lines"`` (stop 29): only the gradient across the
             scan lines (|d/du| on upright rigs; it follows the rings as the seed projects them): the lidar finds
             its edges between horizontal neighbours, so an image edge it can match has a
             horizontal gradient; horizontal image edges are clutter it can never line up;
* ``rows``   |d/du| whatever the rig (stop 28's ``gx``, before it followed the rings);
* ``a05`` / ``a03``  the vertical gradient kept at half / 0.3 weight;
* ``coh``, ``gxcoh``  magnitude / ``gx`` times the structure tensor's coherence (foliage is
             incoherent);
* ``local``  magnitude over its local mean (busy regions flattened);
* ``log``    the gradient of log brightness (a multiplicative light drops out).

    L2E_REALDATA=../shared/realdata PYTHONPATH=$PWD python benchmarks/bench_edge_maps.py \\
        --rigs synth_vlp16_8,synth_os128_8,hitsz_vlp16,lcecalib_rlfs01 --variants base,gx --seeds 7

With ``--verdict N`` it runs the whole engine instead (optimiser and verdict, ``bench_realdata``'s
rows: N runs from each of 1 deg / 5 cm, 2 deg / 10 cm and 5 deg / 20 cm, and 2 from the
reference), one row set per candidate, so closer / kept / worse and trusted-but-worse compare.

Rig names: those of ``realdata_rigs.ALL`` and ``synth_<lidar>_<scenes>`` (e.g. ``synth_vlp16_8``).
"""

from __future__ import annotations

import argparse
import json
import time
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np

from l2e_studio.calibrate import CalibrationSettings, calibrate, stack_scenes
from l2e_studio.scoring import edges
from realdata_rigs import load_rigs, perturbations, synthetic_rigs

ENGINE = edges.scan_gradient


def _coherence(gx: np.ndarray, gy: np.ndarray, sigma: float = 2.0) -> np.ndarray:
    jxx, jyy, jxy = (cv2.GaussianBlur(a, (0, 0), sigma) for a in (gx * gx, gy * gy, gx * gy))
    return np.sqrt((jxx - jyy) ** 2 + 4 * jxy ** 2) / (jxx + jyy + 1e-6)


def _anisotropic(vertical: float):
    def gradient(image: np.ndarray, scan) -> np.ndarray:
        gx, gy = edges.sobel(image)
        return edges.unit_p99(edges.magnitude(gx, vertical * gy))
    return gradient


def _centre(image, scan):
    """The engine's, with the scan direction at the image centre everywhere (no curvature)."""
    h, w = scan.shape[:2]
    return ENGINE(image, np.broadcast_to(scan[h // 2, w // 2], scan.shape))


def _cos2(image, scan):
    """|grad| cos² of its angle to the scan lines: an edge the rings cross obliquely counts less."""
    gx, gy = edges.sobel(image)
    along = np.abs(gx * scan[..., 0] + gy * scan[..., 1])
    return edges.unit_p99(along * along / (edges.magnitude(gx, gy) + 1e-6))


def _blur2(image, scan):
    return edges.unit_p99(edges.magnitude(*edges.sobel(image, 2.0)))


def _coh(image, scan):
    gx, gy = edges.sobel(image)
    return edges.unit_p99(edges.magnitude(gx, gy) * _coherence(gx, gy))


def _gxcoh(image, scan):
    gx, gy = edges.sobel(image)
    return edges.unit_p99(np.abs(gx) * _coherence(gx, gy))


def _local(image, scan):
    m = edges.gradient_magnitude(image)
    return edges.unit_p99(m / (cv2.GaussianBlur(m, (0, 0), 8.0) + 0.1))


def _log(image, scan):
    return edges.unit_p99(edges.magnitude(*edges.sobel(np.log1p(np.asarray(image, np.float32)))))


VARIANTS = {"base": lambda image, scan: edges.gradient_magnitude(image), "blur2": _blur2, "gx": ENGINE,
            "rows": _anisotropic(0.0), "centre": _centre, "cos2": _cos2, "a05": _anisotropic(0.5),
            "a03": _anisotropic(0.3), "coh": _coh, "gxcoh": _gxcoh, "local": _local, "log": _log}


@contextmanager
def gradient(name: str):
    """The engine with candidate ``name`` as its image gradient, for the block's duration."""
    edges.scan_gradient = VARIANTS[name]
    try:
        yield
    finally:
        edges.scan_gradient = ENGINE


def rigs_named(names: list[str]):
    real = [n for n in names if not n.startswith("synth_")]
    rigs = load_rigs(real) if real else []
    for n in names:
        if n.startswith("synth_"):
            _, lidar, k = n.split("_")
            rigs += synthetic_rigs([lidar], [int(k)])
    return rigs


def board_solve(rig):
    if rig.board is None:
        return None
    from l2e_studio.target import calibrate_target, load_target

    return calibrate_target(rig.scenes, rig.camera, rig.reference, load_target(rig.board), use_cache=False).extrinsic


def run(rig, variant: str, seeds: int, board) -> dict:
    settings = CalibrationSettings(edge_gradient="scan-lines")  # the engine's gradient step is the one swapped
    with gradient(variant):
        stack = stack_scenes(rig.scenes, rig.camera, rig.reference,
                             CalibrationSettings(translation_bound=0.5, rotation_bound_deg=20.0, edge_gradient="scan-lines"))
        final = stack.with_sigma(settings.sigma)
        at_ref = final.score(rig.reference, per_scene=False)[0]
        ends = []
        t0 = time.perf_counter()
        for dt, dr in [(np.zeros(3), np.zeros(3))] + perturbations(seeds, 2.0, 0.10, 1001):
            end = calibrate(stack, None, rig.reference.perturbed(dt, dr), settings).extrinsic
            e = end.error_to(rig.reference)
            b = end.error_to(board) if board is not None else (np.nan, np.nan)
            ends.append(dict(deg=e[0], cm=100 * e[1], ratio=final.score(end, per_scene=False)[0] / at_ref if at_ref > 0 else np.nan,
                             board_deg=b[0], board_cm=100 * b[1]))
    return dict(rig=rig.name, variant=variant, from_reference=ends[0], from_seeds=ends[1:], seconds=time.perf_counter() - t0)


def table(rows: list[dict]) -> str:
    """The optimiser-alone rows as a table; the whole engine's (``--verdict``) as bench_realdata's."""
    if rows and "cls" in rows[0]:
        from bench_realdata import table as verdict_table

        return verdict_table(rows)
    lines = ["| rig | map | from the reference | 2 deg / 10 cm seeds: median (worst) | to the board, median |",
             "|---|---|---|---|---|"]
    for r in rows:
        s, f = r["from_seeds"], r["from_reference"]
        med = f"{np.median([e['deg'] for e in s]):.2f} deg / {np.median([e['cm'] for e in s]):.1f} cm ({max(e['deg'] for e in s):.2f} deg)" if s else "-"
        board = f"{np.median([e['board_deg'] for e in s]):.2f} deg / {np.median([e['board_cm'] for e in s]):.1f} cm" if s and np.isfinite(f["board_deg"]) else "-"
        lines.append(f"| {r['rig']} | {r['variant']} | {f['deg']:.2f} deg / {f['cm']:.1f} cm | {med} | {board} |")
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rigs", default="synth_vlp16_8,synth_os128_8,hitsz_vlp16,lcecalib_rlfs01,lcecalib_rles01_frame")
    p.add_argument("--variants", default="base,gx")
    p.add_argument("--seeds", type=int, default=7, help="starts 2 deg / 10 cm off the reference, besides the reference")
    p.add_argument("--verdict", type=int, default=0, help="runs a seed level through the whole engine (bench_realdata's rows)")
    p.add_argument("--save", type=Path, help="rows as JSON")
    p.add_argument("--table", type=Path, nargs="*", help="print the table of saved rows and exit")
    args = p.parse_args()
    if args.table:
        print(table([r for path in args.table for r in json.loads(path.read_text())]))
        return
    rows = []
    for rig in rigs_named(args.rigs.split(",")):
        if args.verdict:
            from bench_realdata import LEVELS, run_rig

            for variant in args.variants.split(","):
                with gradient(variant):
                    rows += [dict(r, engine=variant) for r in run_rig(rig, args.verdict, list(LEVELS.values()), ["scan"])]
            continue
        board = board_solve(rig)
        for variant in args.variants.split(","):
            rows.append(run(rig, variant, args.seeds, board))
            r = rows[-1]
            print(f"{rig.name:22s} {variant:6s} from the reference {r['from_reference']['deg']:.2f} deg / "
                  f"{r['from_reference']['cm']:.1f} cm; seeds: " + ", ".join(f"{e['deg']:.2f}/{e['cm']:.1f}" for e in r["from_seeds"])
                  + f" [{r['seconds']:.0f} s]", flush=True)
    print(table(rows))
    if args.save:
        args.save.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
