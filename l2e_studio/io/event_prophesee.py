"""Prophesee recordings: ``.raw`` (EVT 2.0, EVT 3.0) and ``.dat`` decoders, plus encoders.

Both containers start with ASCII header lines beginning with ``%``; the binary data follows.

* EVT 2.0: little-endian 32-bit words, type in bits 31..28. CD_OFF (0x0) / CD_ON (0x1) carry
  the 6 low timestamp bits (27..22), x (21..11) and y (10..0); EVT_TIME_HIGH (0x8) carries the
  28 high timestamp bits. Other types (triggers, vendor data) are skipped.
* EVT 3.0: little-endian 16-bit words, type in bits 15..12, decoded with a state machine
  (Prophesee's public format description): EVT_ADDR_Y (0x0) sets y; EVT_ADDR_X (0x2) emits one
  event at x with polarity bit 11; VECT_BASE_X (0x3) sets a base x and polarity; VECT_12 (0x4)
  and VECT_8 (0x5) emit one event per set bit of a 12/8-bit mask at base x + bit, then advance
  base x by 12/8; EVT_TIME_LOW (0x6) and EVT_TIME_HIGH (0x8) set the low/high 12 bits of a
  24-bit microsecond time base, which wraps every 16.7 s (wraps are unrolled here).
  The decoder is vectorised: forward fills (``np.maximum.accumulate`` over word indices) replace
  the per-word loop, and the state (y, base x, polarity, time) is carried across chunks.
* DAT: after the header, one byte event type and one byte event size (8), then records of a
  uint32 timestamp (us) and a uint32 with x in bits 0..13, y in 14..27, polarity in 28..31.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, Iterator

import numpy as np

from ..errors import InputError

#: Sensor sizes by Prophesee plugin / sensor generation, for headers without a geometry line.
_GENERATION_SIZES = (
    (re.compile(r"imx636|gen4|evk4|gen41|4\.1"), (1280, 720)),
    (re.compile(r"genx320|gen ?x ?320"), (320, 320)),
    (re.compile(r"gen3|gen31|3\.1|3\.0|evk2|evk1"), (640, 480)),
    (re.compile(r"imx8|gen2|atis"), (304, 240)),
)


@dataclass
class Header:
    """What the ``%`` header of a RAW/DAT file says."""

    lines: list[str]
    data_offset: int
    encoding: str | None  # "evt2", "evt3", "evt21" or None
    size: tuple[int, int] | None


def read_header(path: Path) -> Header:
    """Parse the ``%`` header lines at the start of a Prophesee file."""
    lines: list[str] = []
    with open(path, "rb") as f:
        offset = 0
        while True:
            first = f.read(1)
            if first != b"%":
                break
            line = first + f.readline()
            offset += len(line)
            text = line.decode("latin-1").strip()
            lines.append(text)
            if text == "% end":
                break
            if len(lines) > 10000:
                raise InputError(path, "header never ends (not a Prophesee file?)")
    return Header(lines, offset, _encoding(lines), _size(lines))


def _encoding(lines: list[str]) -> str | None:
    for line in lines:
        low = line.lower()
        m = re.match(r"%\s*evt\s+(\d)\.(\d)", low)
        if m:
            return {"20": "evt2", "21": "evt21", "30": "evt3"}.get(m.group(1) + m.group(2), f"evt{m.group(1)}{m.group(2)}")
        m = re.match(r"%\s*format\s+evt\s*(\d)(?:\.(\d))?", low)
        if m:
            return {"2": "evt2", "3": "evt3"}.get(m.group(1) if m.group(2) in (None, "0") else "21", "evt21")
    return None


def _size(lines: list[str]) -> tuple[int, int] | None:
    width = height = None
    for line in lines:
        low = line.lower()
        m = re.match(r"%\s*geometry\s+(\d+)\s*x\s*(\d+)", low)
        if m:
            return int(m.group(1)), int(m.group(2))
        m = re.match(r"%\s*format\s+\S*", low)
        if m:
            w = re.search(r"width=(\d+)", low)
            h = re.search(r"height=(\d+)", low)
            if w and h:
                return int(w.group(1)), int(h.group(1))
        m = re.match(r"%\s*width\s+(\d+)", low)
        if m:
            width = int(m.group(1))
        m = re.match(r"%\s*height\s+(\d+)", low)
        if m:
            height = int(m.group(1))
    if width and height:
        return width, height
    for line in lines:
        low = line.lower()
        if low.startswith(("% plugin_name", "% sensor_generation", "% sensor_name", "% camera_integrator")):
            value = low.split(None, 2)[-1]
            for pattern, size in _GENERATION_SIZES:
                if pattern.search(value):
                    return size
    return None


# --- decoding ------------------------------------------------------------------------------

def _ffill_index(mask: np.ndarray) -> np.ndarray:
    """For each position, the index of the last True at or before it (-1 if none)."""
    idx = np.where(mask, np.arange(mask.size), -1)
    return np.maximum.accumulate(idx) if idx.size else idx


def _read_words(f: BinaryIO, dtype: str, count: int) -> np.ndarray:
    data = f.read(count * np.dtype(dtype).itemsize)
    usable = len(data) - len(data) % np.dtype(dtype).itemsize
    return np.frombuffer(data[:usable], dtype=dtype)


def decode_evt2(path: Path, header: Header, chunk_words: int) -> Iterator[tuple[np.ndarray, ...]]:
    """Yield (x, y, t_us, p) arrays for successive chunks of an EVT 2.0 stream."""
    time_high = 0
    with open(path, "rb") as f:
        f.seek(header.data_offset)
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


def decode_evt3(path: Path, header: Header, chunk_words: int) -> Iterator[tuple[np.ndarray, ...]]:
    """Yield (x, y, t_us, p) arrays for successive chunks of an EVT 3.0 stream."""
    s = _Evt3State()
    bits = np.arange(12, dtype=np.uint16)
    with open(path, "rb") as f:
        f.seek(header.data_offset)
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


def decode_dat(path: Path, header: Header, chunk_events: int) -> Iterator[tuple[np.ndarray, ...]]:
    """Yield (x, y, t_us, p) arrays for successive chunks of a DAT file."""
    with open(path, "rb") as f:
        f.seek(header.data_offset)
        type_size = f.read(2)
        if len(type_size) < 2:
            raise InputError(path, "DAT file ends before its event type/size bytes")
        size = type_size[1]
        if size != 8:
            raise InputError(path, f"DAT event size is {size} bytes; only 8-byte CD events are supported")
        wrap = 0
        last_t = None
        while True:
            rec = _read_words(f, "<u4", 2 * chunk_events)
            if rec.size < 2:
                return
            rec = rec[: rec.size - rec.size % 2].reshape(-1, 2)
            t = rec[:, 0].astype(np.int64)
            prev = np.concatenate([[t[0] if last_t is None else last_t], t[:-1]])
            t = t + ((np.cumsum(prev - t > 2**31) + wrap) << 32)
            wrap = int((t[-1] >> 32))
            last_t = int(rec[-1, 0])
            d = rec[:, 1]
            yield ((d & 0x3FFF).astype(np.uint16), ((d >> 14) & 0x3FFF).astype(np.uint16), t,
                   ((d >> 28) & 0xF).astype(np.uint8))


# --- encoding (tests, benchmarks, synthetic data) -------------------------------------------

def _header_bytes(lines: list[str]) -> bytes:
    return "".join(f"% {line}\n" for line in lines).encode("ascii")


def encode_evt2(x, y, t_us, p, width: int, height: int) -> bytes:
    """An EVT 2.0 ``.raw`` file (header + words) for time-sorted events."""
    x, y, t, p = (np.asarray(a) for a in (x, y, t_us, p))
    t = t.astype(np.int64)
    high = (t >> 6).astype(np.uint32)
    new_high = np.ones(t.size, bool)
    new_high[1:] = high[1:] != high[:-1]
    words = np.zeros((t.size, 2), np.uint32)
    words[:, 0] = (np.uint32(0x8) << np.uint32(28)) | (high & np.uint32(0x0FFFFFFF))
    words[:, 1] = ((p.astype(np.uint32) & 1) << 28) | ((t & 0x3F).astype(np.uint32) << 22) | \
        ((x.astype(np.uint32) & 0x7FF) << 11) | (y.astype(np.uint32) & 0x7FF)
    keep = np.column_stack([new_high, np.ones(t.size, bool)])
    head = _header_bytes([f"format EVT2;height={height};width={width}", "evt 2.0", f"geometry {width}x{height}", "end"])
    return head + words[keep].astype("<u4").tobytes()


def encode_evt3(x, y, t_us, p, width: int, height: int, vectorize: bool = True) -> bytes:
    """An EVT 3.0 ``.raw`` file for time-sorted events.

    With ``vectorize``, runs of events sharing time, y and polarity with x inside a 12-pixel
    span are packed as VECT_BASE_X + VECT_12 / VECT_8 words (what real sensors emit); the rest
    are single EVT_ADDR_X words. Vectorised with numpy so benchmarks can write large files.
    """
    x, y, t, p = (np.asarray(a).astype(np.int64) for a in (x, y, t_us, p))
    n = t.size
    high, low = (t >> 12) & 0xFFF, t & 0xFFF
    new_high = np.ones(n, bool)
    new_low = np.ones(n, bool)
    new_y = np.ones(n, bool)
    if n:
        new_high[1:] = (t[1:] >> 12) != (t[:-1] >> 12)
        new_low[1:] = new_high[1:] | (low[1:] != low[:-1])
        new_y[1:] = new_low[1:] | (y[1:] != y[:-1])
    # Group events for vectors: same (t, y, p), consecutive, x in [x0, x0 + 12), increasing x.
    if vectorize and n:
        same = np.zeros(n, bool)
        same[1:] = ~new_y[1:] & (p[1:] == p[:-1]) & (x[1:] > x[:-1])
        group = np.cumsum(~same) - 1
        start = np.flatnonzero(~same)
        # Split groups whose span exceeds 12 pixels: restart wherever x - x0 >= 12.
        x0 = x[start][group]
        over = (x - x0) >= 12
        while over.any():
            first_over = over & ~np.concatenate([[False], over[:-1] & (group[1:] == group[:-1])])
            same = same & ~first_over
            group = np.cumsum(~same) - 1
            start = np.flatnonzero(~same)
            x0 = x[start][group]
            over = (x - x0) >= 12
        is_vec_group = np.bincount(group) >= 3
    else:
        group = np.arange(n)
        start = np.arange(n)
        is_vec_group = np.zeros(n, bool)
    first = np.zeros(n, bool)
    first[start] = True
    ev_vec = is_vec_group[group]
    # Each event may emit: TIME_HIGH, TIME_LOW, ADDR_Y, then ADDR_X (single) or, for the first
    # event of a vector group, VECT_BASE_X + VECT_12 (mask of the group).
    words = np.zeros((n, 5), np.uint16)
    keep = np.zeros((n, 5), bool)
    words[:, 0] = (0x8 << 12) | high
    keep[:, 0] = new_high
    words[:, 1] = (0x6 << 12) | low
    keep[:, 1] = new_low
    words[:, 2] = (0x0 << 12) | (y & 0x7FF)
    keep[:, 2] = new_y
    words[:, 3] = np.where(ev_vec, (0x3 << 12) | (p << 11) | (x & 0x7FF), (0x2 << 12) | (p << 11) | (x & 0x7FF))
    keep[:, 3] = ~ev_vec | first
    if ev_vec.any():
        x0 = x[start][group]
        mask = np.zeros(len(start), np.int64)
        np.bitwise_or.at(mask, group[ev_vec], 1 << (x - x0)[ev_vec])
        grp_first = start[is_vec_group]
        narrow = mask[is_vec_group] < 256
        words[grp_first, 4] = np.where(narrow, (0x5 << 12) | mask[is_vec_group], (0x4 << 12) | mask[is_vec_group])
        keep[grp_first, 4] = True
    head = _header_bytes([f"format EVT3;height={height};width={width}", "evt 3.0", f"geometry {width}x{height}", "end"])
    return head + words[keep].astype("<u2").tobytes()


def encode_dat(x, y, t_us, p, width: int | None = None, height: int | None = None) -> bytes:
    """A DAT (v2, CD events) file."""
    x, y, t, p = (np.asarray(a).astype(np.uint32) for a in (x, y, t_us, p))
    lines = ["Data file containing CD events", "Version 2"]
    if width and height:
        lines += [f"Width {width}", f"Height {height}"]
    rec = np.column_stack([t, (x & 0x3FFF) | ((y & 0x3FFF) << 14) | ((p & 0xF) << 28)]).astype("<u4")
    return _header_bytes(lines) + bytes([0x0C, 8]) + rec.tobytes()
