"""Events per second accumulated from generated EVT3 / HDF5 recordings, and peak memory.

    python benchmarks/bench_accumulate.py [--events 20e6] [--format evt3|h5|both]

Each measurement runs in a fresh subprocess so its peak RSS (ru_maxrss) is its own. Files of
two sizes are accumulated: with streaming, peak memory must stay about the same when the file
grows. Files go to benchmarks/out/ (git-ignored) and are deleted afterwards.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

OUT = Path(__file__).resolve().parent / "out"
W, H = 1280, 720


def generate(path: Path, n: int, fmt: str, block: int = 2_000_000) -> None:
    """A static-scene-like recording: laser returns at fixed pixels, 1 M events/s, in blocks."""
    from l2e_studio.io.event_prophesee import encode_evt3

    rng = np.random.default_rng(0)
    hot = rng.integers(0, W * H, 20_000)  # pixels hit by laser returns
    if fmt == "h5":
        import h5py

        f = h5py.File(path, "w")
        g = f.create_group("events")
        ds = {k: g.create_dataset(k, (n,), dtype=d, chunks=(1 << 20,))
              for k, d in (("x", "u2"), ("y", "u2"), ("t", "i8"), ("p", "u1"))}
    else:
        f = open(path, "wb")
    t0 = 0
    for start in range(0, n, block):
        m = min(block, n - start)
        pix = hot[rng.integers(0, hot.size, m)]
        x, y = pix % W, pix // W
        t = t0 + np.sort(rng.integers(0, m, m))  # ~1 event per us
        t0 += m
        order = np.lexsort((x, y, t))
        x, y, t = x[order], y[order], t[order]
        p = rng.integers(0, 2, m)
        if fmt == "h5":
            for k, v in (("x", x), ("y", y), ("t", t), ("p", p)):
                ds[k][start:start + m] = v
        else:
            data = encode_evt3(x, y, t, p, W, H)
            if start:
                data = data[data.index(b"% end\n") + 6:]
            f.write(data)
    f.close()


def measure(path: str, window: float) -> None:
    """Child process: accumulate and print JSON with the timing and peak RSS."""
    from l2e_studio.io.events import accumulate_events

    t = time.perf_counter()
    m = accumulate_events(path, window_s=window, clip=None)
    dt = time.perf_counter() - t
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps({"seconds": dt, "events": int(m.sum()), "peak_rss_mb": rss}))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--events", type=float, default=20e6, help="events in the large file (small = 1/4)")
    ap.add_argument("--format", choices=("evt3", "h5", "both"), default="both")
    ap.add_argument("--measure", nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.measure:
        measure(args.measure[0], float(args.measure[1]))
        return
    OUT.mkdir(parents=True, exist_ok=True)
    fmts = ("evt3", "h5") if args.format == "both" else (args.format,)
    print(f"{'format':6s} {'events':>11s} {'file MB':>8s} {'s':>6s} {'Mev/s':>7s} {'peak RSS MB':>11s}")
    for fmt in fmts:
        for n in (int(args.events) // 4, int(args.events)):
            path = OUT / f"bench_{n}.{'raw' if fmt == 'evt3' else 'h5'}"
            generate(path, n, fmt)
            res = subprocess.run([sys.executable, __file__, "--measure", str(path), "1e9"],
                                 capture_output=True, text=True, check=True)
            r = json.loads(res.stdout.strip().splitlines()[-1])
            assert r["events"] == n, (r, n)
            size = path.stat().st_size / 1e6
            print(f"{fmt:6s} {n:11d} {size:8.1f} {r['seconds']:6.2f} {n / r['seconds'] / 1e6:7.2f} {r['peak_rss_mb']:11.0f}",
                  flush=True)
            path.unlink()


if __name__ == "__main__":
    main()
