"""Regenerate the embedded sample scenes in ``assets/sample`` (deterministic).

    python benchmarks/make_sample_assets.py            # writes assets/sample (replacing it)
    python benchmarks/make_sample_assets.py --check    # + calibrate it from its seed, print errors

Same as ``l2e-studio synth --preset sample --out assets/sample --force``: six garage scenes,
640 x 360 event maps, ~20k lidar points each, the seed 2 deg / 5 cm off the truth.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from l2e_studio.synth import SAMPLE_CONFIG, read_truth, write_dataset

ASSETS = Path(__file__).resolve().parents[1] / "assets" / "sample"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=ASSETS)
    ap.add_argument("--check", action="store_true", help="calibrate the written sample from its seed")
    args = ap.parse_args()
    t0 = time.perf_counter()
    out = write_dataset(args.out, SAMPLE_CONFIG, overwrite=True)
    size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    print(f"wrote {out} ({size / 1e6:.2f} MB) in {time.perf_counter() - t0:.1f} s")
    if args.check:
        from l2e_studio.calibrate import calibrate
        from l2e_studio.scenes import load_scene_folder

        ss = load_scene_folder(out, use_cache=False)
        truth = read_truth(out / "truth.yaml")
        res = calibrate(ss.scenes, ss.camera, ss.seed)
        for name, ext in (("seed", ss.seed), ("result", res.extrinsic)):
            deg, m = ext.error_to(truth)
            print(f"{name}: {deg:.3f} deg, {m * 1000:.1f} mm from the truth")
        print(f"MI {res.score_seed:.4f} -> {res.score_result:.4f} in {res.seconds:.1f} s ({res.evaluations} evaluations)")


if __name__ == "__main__":
    main()
