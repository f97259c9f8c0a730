"""The numpy EVT 2.0 / 3.0 decoders the project used before the compiled ones (io/event_codecs.py):
forward fills (``np.maximum.accumulate`` over word indices) in place of the per-word loop, state
carried across chunks. Kept as the reference the compiled decoders must match event for event
(tests/test_event_codecs.py) and as the "before" of benchmarks/bench_accumulate.py."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, Iterator

import numpy as np


def _ffill_index(mask: np.ndarray) -> np.ndarray:
    """For each position, the index of the last True at or before it (-1 if none)."""
    idx = np.where(mask, np.arange(mask.size), -1)
    return np.maximum.accumulate(idx) if idx.size else idx


def _read_words(f: BinaryIO, dtype: str, count: int) -> np.ndarray:
    data = f.read(count * np.dtype(dtype).itemsize)
    usable = len(data) - len(data) % np.dtype(dtype).itemsize
    return np.frombuffer(data[:usable], dtype=dtype)


def decode_evt2(path: Path, data_offset: int, chunk_words: int) -> Iterator[tuple[np.ndarray, ...]]:
    """Yield (x, y, t_us, p) arrays for successive chunks of an EVT 2.0 stream."""
    time_high = 0
    with open(path, "rb") as f:
        f.seek(data_offset)
        while True:
            w = _read_words(f, "<u4", chunk_words)
            if w.size == 0:
                return
            kind = w >> 28
            is_th = kind == 0x8
            last = _ffill_index(is_th)
            th = np.where(last >= 0, w[np.maximum(last, 0)] & 0x0FFFFFFF, time_high).astype(np.int64)
            if is_th.any():
                time_high = int(w[np.flatnonzero(is_th)[-1]] & 0x0FFFFFFF)
            cd = kind <= 0x1
            wc = w[cd]
            t = (th[cd] << 6) | ((wc >> 22) & 0x3F).astype(np.int64)
            yield ((wc >> 11) & 0x7FF).astype(np.uint16), (wc & 0x7FF).astype(np.uint16), t, kind[cd].astype(np.uint8)


@dataclass
class _Evt3State:
    y: int = 0
    base_x: int = 0  # including the advance of vectors already seen
    vec_pol: int = 0
    time_high: int = 0  # unrolled (wraps added), in units of 4096 us
    time_low: int = 0
    last_raw_high: int | None = None


def decode_evt3(path: Path, data_offset: int, chunk_words: int) -> Iterator[tuple[np.ndarray, ...]]:
    """Yield (x, y, t_us, p) arrays for successive chunks of an EVT 3.0 stream."""
    s = _Evt3State()
    bits = np.arange(12, dtype=np.uint16)
    with open(path, "rb") as f:
        f.seek(data_offset)
        while True:
            w = _read_words(f, "<u2", chunk_words)
            if w.size == 0:
                return
            yield _evt3_chunk(w, s, bits)


def _evt3_chunk(w: np.ndarray, s: _Evt3State, bits: np.ndarray) -> tuple[np.ndarray, ...]:
    kind = w >> 12
    payload = (w & 0x0FFF).astype(np.int64)

    # Time: unroll the 12-bit high counter (it wraps every 2**24 us), forward-fill high and low.
    is_th = kind == 0x8
    th_raw = payload[is_th]
    if th_raw.size:
        prev = np.concatenate([[s.last_raw_high if s.last_raw_high is not None else th_raw[0]], th_raw[:-1]])
        wraps = np.cumsum(th_raw < prev)
        base_high = s.time_high - (s.time_high % 4096) if s.last_raw_high is not None else 0
        th_full = base_high + th_raw + 4096 * wraps
    else:
        th_full = th_raw
    hi_idx = _ffill_index(is_th)
    rank_hi = np.cumsum(is_th) - 1
    high = np.where(hi_idx >= 0, th_full[np.maximum(rank_hi, 0)] if th_full.size else 0, s.time_high)
    is_tl = kind == 0x6
    tl_vals = payload[is_tl]
    rank_tl = np.cumsum(is_tl) - 1
    low = np.where(rank_tl >= 0, tl_vals[np.maximum(rank_tl, 0)] if tl_vals.size else 0, s.time_low)
    t = (high.astype(np.int64) << 12) | low

    # y, forward-filled.
    is_y = kind == 0x0
    rank_y = np.cumsum(is_y) - 1
    y_vals = payload[is_y] & 0x7FF
    y = np.where(rank_y >= 0, y_vals[np.maximum(rank_y, 0)] if y_vals.size else 0, s.y)

    # Single events.
    single = kind == 0x2
    xs, ys, ts = payload[single] & 0x7FF, y[single], t[single]
    ps = (payload[single] >> 11) & 1

    # Vector events: x = base x + advance of earlier vectors since that base + bit index.
    is_base = kind == 0x3
    is_v12, is_v8 = kind == 0x4, kind == 0x5
    width = np.where(is_v12, 12, np.where(is_v8, 8, 0))
    advance = np.cumsum(width) - width  # advance before each word, counted from the chunk start
    rank_b = np.cumsum(is_base) - 1
    base_vals = payload[is_base] & 0x7FF
    base_adv = advance[is_base]
    base_pol = (payload[is_base] >> 11) & 1
    has_base = rank_b >= 0
    rb = np.maximum(rank_b, 0)
    if base_vals.size:
        vx0 = np.where(has_base, base_vals[rb] - base_adv[rb] + advance, s.base_x + advance)
        vpol = np.where(has_base, base_pol[rb], s.vec_pol)
    else:
        vx0 = s.base_x + advance
        vpol = np.full(w.size, s.vec_pol)
    is_vec = is_v12 | is_v8
    if is_vec.any():
        vi = np.flatnonzero(is_vec)
        nbits = np.where(is_v12[vi], 12, 8)
        mask = payload[vi].astype(np.uint16) & np.where(is_v12[vi], 0xFFF, 0xFF).astype(np.uint16)
        on = ((mask[:, None] >> bits[None, :]) & 1).astype(bool) & (bits[None, :] < nbits[:, None])
        r, c = np.nonzero(on)
        word = vi[r]
        vx = vx0[word] + c
        xs = np.concatenate([xs, vx])
        ys = np.concatenate([ys, y[word]])
        ts = np.concatenate([ts, t[word]])
        ps = np.concatenate([ps, vpol[word]])
        order = np.argsort(np.concatenate([np.flatnonzero(single), word]), kind="stable")
        xs, ys, ts, ps = xs[order], ys[order], ts[order], ps[order]

    # Carry the state into the next chunk.
    if th_full.size:
        s.time_high = int(th_full[-1])
        s.last_raw_high = int(th_raw[-1])
    if tl_vals.size:
        s.time_low = int(tl_vals[-1])
    if y_vals.size:
        s.y = int(y_vals[-1])
    end_adv = int(advance[-1] + width[-1])
    if base_vals.size:
        s.base_x = int(base_vals[-1] + end_adv - base_adv[-1])
        s.vec_pol = int(base_pol[-1])
    else:
        s.base_x += end_adv
    return xs.astype(np.uint16), ys.astype(np.uint16), ts.astype(np.int64), ps.astype(np.uint8)
