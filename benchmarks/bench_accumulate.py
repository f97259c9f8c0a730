"""Event decoding and accumulation rates from generated recordings, and peak memory.

    python benchmarks/bench_accumulate.py [--events 50e6] [--format evt3|evt2|h5|all] [--no-accumulate]

For EVT 3.0 and EVT 2.0 ``.raw`` files: the decode rate of the numpy decoders the project used
before (tests/evt_reference.py, "before") and of the compiled ones (io/event_codecs.py, "after"),
then the accumulation rate (decode + time-order check + counting into the map); for HDF5 the
accumulation rate. Each measurement runs in a fresh subprocess so its peak RSS (VmHWM) is its own; files of two sizes (N/4 and N events) show that memory stays flat when the file grows. Rates
are given in wall time and in the process's CPU time (on a loaded machine the CPU time is the
fairer number). Files go to a temporary folder and are deleted afterwards.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
W, H = 1280, 720
#: EventPacket sizes measured for EVT 3.0: a small packet (16 KiB, ~1 ms of a quiet scene) and 1 MiB.
PACKET_BYTES = (16 * 1024, 1024 * 1024)


def generate(path: Path, n: int, fmt: str, block: int = 2_000_000) -> None:
    """A static-scene-like recording: laser returns at fixed pixels, 1 M events/s, in blocks
    (EVT 3.0 times wrap at 2^24 us, every 16.7 s: a 50 M event file crosses it twice)."""
    from l2e_studio.io.event_prophesee import encode_evt2, encode_evt3

    rng = np.random.default_rng(0)
    hot = rng.integers(0, W * H, 20_000)  # pixels hit by laser returns
    if fmt == "h5":
        import h5py

        f = h5py.File(path, "w")
        g = f.create_group("events")
        ds = {k: g.create_dataset(k, (n,), dtype=d, chunks=(min(1 << 20, n),))
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
            data = (encode_evt3 if fmt == "evt3" else encode_evt2)(x, y, t, p, W, H)
            if start:
                data = data[data.index(b"% end\n") + 6:]
            f.write(data)
    f.close()


def measure(path: str, what: str) -> None:
    """Child process: decode ("before" / "after") or accumulate, print JSON with the timing and peak RSS."""
    from l2e_studio.io import event_codecs, event_prophesee as pr
    from l2e_studio.io.events import accumulate_events

    sys.path.insert(0, str(ROOT / "tests"))
    import evt_reference as ref

    # numba's kernels loaded from its cache (or compiled) before the clock starts
    list(event_codecs.Evt3Decoder().decode(np.zeros(4, np.uint16)))
    list(event_codecs.Evt2Decoder().decode(np.zeros(4, np.uint32)))
    readonly = np.zeros(4, np.uint16)
    readonly.flags.writeable = False  # packets are read-only views of the message (another specialisation)
    list(event_codecs.Evt3Decoder().decode(readonly))
    header = pr.read_header(Path(path)) if path.endswith(".raw") else None
    n = 0
    wall, cpu = time.perf_counter(), time.process_time()
    if what == "accumulate":
        n = int(accumulate_events(path, window_s=1e9, clip=None).sum())
    elif what.startswith("packets"):
        n = _decode_as_packets(Path(path), header.data_offset, int(what.split(":")[1]))
    else:
        if what == "before":
            decode = ref.decode_evt3 if header.encoding == "evt3" else ref.decode_evt2
            chunks = decode(Path(path), header.data_offset, 2_000_000)
        else:
            decode = pr.decode_evt3 if header.encoding == "evt3" else pr.decode_evt2
            chunks = decode(Path(path), header, 2_000_000)
        for x, _, _, _ in chunks:
            n += x.size
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    print(json.dumps({"seconds": wall, "cpu_seconds": cpu, "events": n, "peak_rss_mb": _peak_rss_mb()}))


def _decode_as_packets(path: Path, offset: int, packet_bytes: int) -> int:
    """The file's EVT 3.0 words cut into ``event_camera_msgs/EventPacket``s of ``packet_bytes``
    each (metavision_driver publishes the SDK's buffers as they come, cut anywhere) and decoded by
    the bag readers' own :class:`PacketStream`, one packet in memory at a time."""
    from types import SimpleNamespace

    from l2e_studio.io.event_packets import PacketStream

    stream = PacketStream("/bench/events")
    n = 0
    with open(path, "rb") as f:
        f.seek(offset)
        while payload := f.read(packet_bytes):  # a fresh buffer a message, as a bag reader hands them out
            msg = SimpleNamespace(encoding="evt3", is_bigendian=False, time_base=0,
                                  events=np.frombuffer(payload, np.uint8))
            n += stream.decode(msg)[0].size
    return n


def _peak_rss_mb() -> float:
    """This process's peak RSS: VmHWM (ru_maxrss would carry the parent's over the exec)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _child(path: Path, what: str) -> dict:
    res = subprocess.run([sys.executable, __file__, "--measure", str(path), what],
                         capture_output=True, text=True, check=True)
    return json.loads(res.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--events", type=float, default=50e6, help="events in the large file (small = 1/4)")
    ap.add_argument("--format", choices=("evt3", "evt2", "h5", "all"), default="all")
    ap.add_argument("--no-accumulate", action="store_true", help="decode rates only")
    ap.add_argument("--measure", nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.measure:
        measure(*args.measure)
        return
    # compile (or load from numba's cache) the kernels once, outside the measurements
    subprocess.run([sys.executable, "-c", "from l2e_studio.io import event_codecs as c; import numpy as np; "
                    "list(c.Evt3Decoder().decode(np.zeros(4, np.uint16))); list(c.Evt2Decoder().decode(np.zeros(4, np.uint32)))"],
                   check=True)
    fmts = ("evt3", "evt2", "h5") if args.format == "all" else (args.format,)
    print(f"{'format':6s} {'what':16s} {'events':>11s} {'file MB':>8s} {'wall s':>7s} {'Mev/s':>7s} "
          f"{'cpu s':>7s} {'Mev/s cpu':>9s} {'peak RSS MB':>11s}", flush=True)
    with tempfile.TemporaryDirectory(prefix="bench_accumulate_") as tmp:
        for fmt in fmts:
            for n in (int(args.events) // 4, int(args.events)):
                path = Path(tmp) / f"bench_{n}.{'raw' if fmt != 'h5' else 'h5'}"
                generate(path, n, fmt)
                whats = [] if fmt == "h5" else (["before", "after"] if n == int(args.events) else ["after"])
                whats += [f"packets:{b}" for b in PACKET_BYTES] if fmt == "evt3" else []
                whats += [] if args.no_accumulate else ["accumulate"]
                for what in whats:
                    r = _child(path, what)
                    assert r["events"] == n, (r, n)
                    print(f"{fmt:6s} {what:16s} {n:11d} {path.stat().st_size / 1e6:8.1f} {r['seconds']:7.2f} "
                          f"{n / r['seconds'] / 1e6:7.1f} {r['cpu_seconds']:7.2f} {n / r['cpu_seconds'] / 1e6:9.1f} "
                          f"{r['peak_rss_mb']:11.0f}", flush=True)
                path.unlink()


if __name__ == "__main__":
    main()
