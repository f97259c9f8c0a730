"""LZF decompression (the codec of PCD ``binary_compressed``), in pure Python.

LZF is a byte-oriented LZ77 variant: a control byte below 32 starts a literal run of
``ctrl + 1`` bytes; otherwise its top 3 bits are a match length (7 = "read one more length
byte") and its low 5 bits plus the next byte a back-reference distance. Uses the ``lzf`` C
extension (PyPI ``python-neo-lzf``, a dependency; ``python-lzf`` provides the same module) when it is installed, this loop otherwise.
"""

from __future__ import annotations

try:  # optional C extension, much faster on big clouds
    import lzf as _c_lzf  # type: ignore[import-not-found]
except ImportError:  # pragma: no cover - depends on the environment
    _c_lzf = None


#: LZF's largest expansion: 3 input bytes (a long back-reference) give at most 264 output bytes.
MAX_RATIO = 88


def decompress(data: bytes, size: int) -> bytes:
    """Decompress ``data`` to exactly ``size`` bytes; ValueError when it is corrupt."""
    if size > MAX_RATIO * len(data) + 1024:
        raise ValueError(f"{len(data)} compressed bytes cannot expand to {size}")
    if _c_lzf is not None:
        out = _c_lzf.decompress(bytes(data), size + 1)
        if out is None or len(out) != size:
            raise ValueError(f"decompressed to {0 if out is None else len(out)} bytes, expected {size}")
        return out
    return _decompress_py(bytes(data), size)


def _decompress_py(src: bytes, size: int) -> bytes:
    out = bytearray(size)
    ip, op, n = 0, 0, len(src)
    while ip < n:
        ctrl = src[ip]
        ip += 1
        if ctrl < 32:
            run = ctrl + 1
            if ip + run > n or op + run > size:
                raise ValueError("literal run past the end of the data")
            out[op: op + run] = src[ip: ip + run]
            ip += run
            op += run
            continue
        length = ctrl >> 5
        if length == 7:
            if ip >= n:
                raise ValueError("truncated match length")
            length += src[ip]
            ip += 1
        if ip >= n:
            raise ValueError("truncated back-reference")
        ref = op - ((ctrl & 0x1F) << 8) - src[ip] - 1
        ip += 1
        length += 2
        if ref < 0 or op + length > size:
            raise ValueError("back-reference outside the output")
        if ref + length <= op:  # no overlap: one slice copy
            out[op: op + length] = out[ref: ref + length]
        else:  # overlapping copy repeats a short pattern
            dist = op - ref
            pattern = out[ref:op]
            reps = -(-length // dist)
            out[op: op + length] = (pattern * reps)[:length]
        op += length
    if op != size:
        raise ValueError(f"decompressed to {op} bytes, expected {size}")
    return bytes(out)


def compress(data: bytes) -> bytes:
    """A valid (literal-only) LZF stream for ``data``: used by tests to write PCD files."""
    out = bytearray()
    for i in range(0, len(data), 32):
        chunk = data[i: i + 32]
        out.append(len(chunk) - 1)
        out += chunk
    return bytes(out)
