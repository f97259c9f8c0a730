"""Event camera encodings decoded at sensor speed: Prophesee EVT 3.0 and EVT 2.0 words (raw files
and ``event_camera_msgs/EventPacket`` payloads), and the ROS drivers' ``mono`` and ``libcaer``
packets.

A busy Prophesee sensor delivers tens of millions of events a second. EVT 3.0 is a state machine
(a y word, then x words or vector masks that reuse it; time words in between), which numpy can
only express as a dozen forward-fill passes over every chunk (about 4.5 M events/s); the compiled
loops here walk the words once (see ``benchmarks/bench_accumulate.py``). The decoders are objects
carrying their state (y, base x, polarity, time, time wraps) from one call to the next, so a
stream can be cut anywhere -- file chunks, bag messages -- and decodes to the same events; output
comes in pieces of at most ``capacity`` events, so memory stays flat in the recording's length.

EVT 3.0 (Prophesee's public format description; 16-bit little-endian words, type in bits 15..12):
ADDR_Y (0x0) sets y (bits 10..0); ADDR_X (0x2) emits one event at x (10..0), polarity bit 11;
VECT_BASE_X (0x3) sets base x and polarity; VECT_12 (0x4) / VECT_8 (0x5) emit one event per set
bit of a 12 / 8-bit mask at base x + bit, then advance base x by 12 / 8; TIME_LOW (0x6) and
TIME_HIGH (0x8) set the low and high 12 bits of a 24-bit microsecond time, which wraps every
16.7 s (a TIME_HIGH smaller than the one before is a wrap, unrolled here). Other types (triggers,
vendor data) carry no pixel events and are skipped.

EVT 2.0 (32-bit words, type in bits 31..28): CD_OFF (0x0) / CD_ON (0x1) carry the 6 low time bits
(27..22), x (21..11), y (10..0); TIME_HIGH (0x8) the 28 high time bits. Others are skipped.

``mono`` (event_camera_msgs, metavision_driver's older encoding): 64-bit little-endian words,
polarity bit 63, y bits 62..48, x bits 47..32, and bits 31..0 the time in ns after the
message's ``time_base`` (ns). ``libcaer`` (libcaer_driver): 8 bytes an event, a uint32 with
polarity bit 1, y bits 16..2 and x bits 31..17, then an int32 time in us; the time in ns is the
message's ``time_base`` plus 1000 x that, plus 2^31 us for each time that runs backwards inside
the packet (the counter's rollover).
"""

from __future__ import annotations

from typing import Iterator

import numpy as np

from ..compiled import numba

Events = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]  # x, y (uint16), t_us (int64), p (uint8)

#: Most events one decoder call hands back at once (13 bytes each).
DEFAULT_CAPACITY = 1 << 21

_JIT = dict(nogil=True, cache=True, boundscheck=False)

# EVT 3.0 decoder state, an int64 array (numba reads and writes it in place)
_Y, _BASE_X, _POL, _WRAPS, _HIGH, _LOW, _LAST_RAW_HIGH = range(7)


@numba.njit(**_JIT)
def _evt3_kernel(w, i, state, xo, yo, to, po):
    """Decode ``w[i:]`` into the outputs until the words end or fewer than 12 slots are left;
    returns (next word, events written). Words go in blocks that cannot overflow the outputs
    (at most 12 events a word), so the inner loop checks nothing but the word type."""
    y, bx, pol = state[_Y], state[_BASE_X], state[_POL]
    wraps, high, low, last = state[_WRAPS], state[_HIGH], state[_LOW], state[_LAST_RAW_HIGH]
    t = (high << 12) | low
    n = 0
    nw = w.size
    while i < nw:
        stop = min(nw, i + (xo.size - n) // 12)
        if stop <= i:
            break
        for j in range(i, stop):
            word = np.int64(w[j])
            kind = word >> 12
            pay = word & 0xFFF
            if kind == 0x2:  # the most frequent word first
                xo[n] = np.uint16(pay & 0x7FF)
                yo[n] = np.uint16(y)
                to[n] = t
                po[n] = np.uint8((pay >> 11) & 1)
                n += 1
            elif kind == 0x0:
                y = pay & 0x7FF
            elif kind == 0x4 or kind == 0x5:
                m = pay if kind == 0x4 else pay & 0xFF
                x = bx
                while m:  # every slot up to the highest set bit written, the set ones kept
                    xo[n] = np.uint16(x & 0xFFFF)
                    yo[n] = np.uint16(y)
                    to[n] = t
                    po[n] = np.uint8(pol)
                    n += m & 1
                    m >>= 1
                    x += 1
                bx += 12 if kind == 0x4 else 8
            elif kind == 0x3:
                bx = pay & 0x7FF
                pol = (pay >> 11) & 1
            elif kind == 0x6:
                low = pay
                t = (high << 12) | low
            elif kind == 0x8:
                if last >= 0 and pay < last:
                    wraps += 1
                last = pay
                high = wraps * 4096 + pay
                t = (high << 12) | low
        i = stop
    state[_Y], state[_BASE_X], state[_POL] = y, bx, pol
    state[_WRAPS], state[_HIGH], state[_LOW], state[_LAST_RAW_HIGH] = wraps, high, low, last
    return i, n


@numba.njit(**_JIT)
def _evt2_kernel(w, i, state, xo, yo, to, po):
    """Decode ``w[i:]`` (uint32 words) until the words end or the outputs are full; returns
    (next word, events written). ``state[0]``: the last TIME_HIGH."""
    high = state[0]
    n = 0
    stop = min(w.size, i + xo.size)  # at most one event a word
    for j in range(i, stop):
        word = np.int64(w[j])
        kind = word >> 28
        if kind <= 0x1:
            xo[n] = np.uint16((word >> 11) & 0x7FF)
            yo[n] = np.uint16(word & 0x7FF)
            to[n] = (high << 6) | ((word >> 22) & 0x3F)
            po[n] = np.uint8(kind)
            n += 1
        elif kind == 0x8:
            high = word & 0x0FFFFFFF
    state[0] = high
    return stop, n


class _WordDecoder:
    """A stateful decoder of one word stream; :meth:`decode` may be fed any split of the stream."""

    _kernel = None
    word_dtype = "<u2"
    _per_word = 1  # the most events one word holds

    def __init__(self, capacity: int = DEFAULT_CAPACITY) -> None:
        self.state = self._initial_state()
        self.capacity = max(int(capacity), 64)
        self._ratio = 1.0  # events per word so far
        self._tail = b""  # bytes of a word cut by the previous call

    def _initial_state(self) -> np.ndarray:
        return np.zeros(1, np.int64)

    def decode(self, words: np.ndarray) -> Iterator[Events]:
        """Yield the events of ``words`` (this encoding's word dtype) in pieces of at most
        ``capacity`` events; the state carries over to the next call."""
        words = np.ascontiguousarray(words, dtype=self.word_dtype)
        i = 0
        while i < words.size:
            # Outputs sized for the events per word seen so far: fresh buffers are handed out as
            # they are (a copy costs a third of the decoding); one that came out mostly empty is copied.
            left = words.size - i
            guess = int(left * self._ratio * 1.05) + self._per_word
            size = max(64, min(self.capacity, self._per_word * left + self._per_word, guess))
            out = (np.empty(size, np.uint16), np.empty(size, np.uint16), np.empty(size, np.int64),
                   np.empty(size, np.uint8))
            start = i
            i, n = type(self)._kernel(words, i, self.state, *out)
            self._ratio = max(n / max(i - start, 1), 0.01)
            if n:
                yield tuple(a[:n] if 2 * n >= size else a[:n].copy() for a in out)  # type: ignore[misc]

    def decode_bytes(self, data: bytes | np.ndarray) -> Iterator[Events]:
        """:meth:`decode` of a byte string; a word cut at the end is kept for the next call."""
        size = np.dtype(self.word_dtype).itemsize
        buf = self._tail + bytes(data) if self._tail else data
        usable = len(buf) - len(buf) % size
        self._tail = bytes(buf[usable:])
        return self.decode(np.frombuffer(buf, self.word_dtype, usable // size))


class Evt3Decoder(_WordDecoder):
    """EVT 3.0, 16-bit words."""

    _kernel = _evt3_kernel
    word_dtype = "<u2"
    _per_word = 12

    def _initial_state(self) -> np.ndarray:
        state = np.zeros(7, np.int64)
        state[_LAST_RAW_HIGH] = -1  # no TIME_HIGH seen yet: the first one is no wrap
        return state


class Evt2Decoder(_WordDecoder):
    """EVT 2.0, 32-bit words."""

    _kernel = _evt2_kernel
    word_dtype = "<u4"
    _per_word = 1


def concat(pieces: list[Events]) -> Events:
    """One (x, y, t_us, p) tuple from several (empty arrays for none)."""
    if not pieces:
        return (np.zeros(0, np.uint16), np.zeros(0, np.uint16), np.zeros(0, np.int64), np.zeros(0, np.uint8))
    if len(pieces) == 1:
        return pieces[0]
    return tuple(np.concatenate(c) for c in zip(*pieces))  # type: ignore[return-value]


def decode_mono(data: bytes | np.ndarray, time_base_ns: int) -> Events:
    """Events of a ``mono`` EventPacket payload (times in us)."""
    w = np.frombuffer(data, "<u8", len(data) // 8)
    t_ns = np.int64(time_base_ns) + (w & np.uint64(0xFFFFFFFF)).astype(np.int64)
    return (((w >> np.uint64(32)) & np.uint64(0xFFFF)).astype(np.uint16),
            ((w >> np.uint64(48)) & np.uint64(0x7FFF)).astype(np.uint16),
            t_ns // 1000, (w >> np.uint64(63)).astype(np.uint8))


def decode_libcaer(data: bytes | np.ndarray, time_base_ns: int) -> Events:
    """Events of a ``libcaer`` EventPacket payload (times in us)."""
    rec = np.frombuffer(data, np.dtype([("d", "<u4"), ("t", "<i4")]), len(data) // 8)
    d, t_us = rec["d"], rec["t"].astype(np.int64)
    rollovers = np.concatenate([[0], np.cumsum(t_us[1:] < t_us[:-1])]) if t_us.size else t_us
    t_ns = np.int64(time_base_ns) + 1000 * (t_us + (rollovers << 31))
    return (((d >> 17) & 0x7FFF).astype(np.uint16), ((d >> 2) & 0x7FFF).astype(np.uint16),
            t_ns // 1000, ((d >> 1) & 1).astype(np.uint8))


# --- encoders (tests, benchmarks) -----------------------------------------------------------

def encode_mono(x, y, t_ns, p, time_base_ns: int) -> bytes:
    """A ``mono`` payload; ``t_ns - time_base_ns`` must fit 32 bits."""
    dt = np.asarray(t_ns, np.int64) - int(time_base_ns)
    if dt.size and (dt.min() < 0 or dt.max() >= 2**32):
        raise ValueError("mono packets hold times up to 4.29 s after their time base")
    w = (dt.astype(np.uint64) | (np.asarray(x, np.uint64) << np.uint64(32))
         | ((np.asarray(y, np.uint64) & np.uint64(0x7FFF)) << np.uint64(48))
         | ((np.asarray(p, np.uint64) & np.uint64(1)) << np.uint64(63)))
    return w.astype("<u8").tobytes()
