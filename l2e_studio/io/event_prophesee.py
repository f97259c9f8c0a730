"""Prophesee recordings: ``.raw`` (EVT 2.0, EVT 3.0) and ``.dat`` decoders, plus encoders.

Both containers start with ASCII header lines beginning with ``%``; the binary data follows.

* EVT 2.0 (32-bit words) and EVT 3.0 (16-bit words, a state machine): the words after the header
  go, a chunk at a time, through the compiled stateful decoders of
  :mod:`l2e_studio.io.event_codecs` (which also decode ROS EventPackets), so a chunk boundary may
  fall anywhere and memory stays flat in the file's length.
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


# --- decoding (compiled, stateful: io/event_codecs.py) ---------------------------------------

def _read_words(f: BinaryIO, dtype: str, count: int) -> np.ndarray:
    data = f.read(count * np.dtype(dtype).itemsize)
    usable = len(data) - len(data) % np.dtype(dtype).itemsize
    return np.frombuffer(data[:usable], dtype=dtype)


def decode_evt2(path: Path, header: Header, chunk_words: int) -> Iterator[tuple[np.ndarray, ...]]:
    """Yield (x, y, t_us, p) arrays for successive chunks of an EVT 2.0 stream."""
    from .event_codecs import Evt2Decoder

    yield from _decode_words(path, header, chunk_words, Evt2Decoder(chunk_words))


def decode_evt3(path: Path, header: Header, chunk_words: int) -> Iterator[tuple[np.ndarray, ...]]:
    """Yield (x, y, t_us, p) arrays for successive chunks of an EVT 3.0 stream."""
    from .event_codecs import Evt3Decoder

    yield from _decode_words(path, header, chunk_words, Evt3Decoder(chunk_words))


def _decode_words(path: Path, header: Header, chunk_words: int, decoder):
    """The file's words, ``chunk_words`` at a time (read into one reused buffer: the decoder keeps
    none of it), through one stateful decoder; memory is flat in the file's length."""
    words = np.empty(max(int(chunk_words), 1), decoder.word_dtype)
    raw = memoryview(words).cast("B")
    with open(path, "rb") as f:
        f.seek(header.data_offset)
        while True:
            got = f.readinto(raw)
            if not got:
                return
            yield from decoder.decode(words[: got // words.itemsize])


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
