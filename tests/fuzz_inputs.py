"""Mutating a small valid file into many damaged ones, and running a reader over each.

Three kinds of damage (all deterministic for a given seed):

* truncation at every offset (a file cut short: end of file inside a header or a record);
* byte flips: a few random bytes set to random values;
* header lies: a header field replaced by a value the data cannot back (a count of billions,
  a negative size, a sensor larger than any...), given per format.

A case passes when the reader returns a result its ``check`` accepts or raises
:class:`~l2e_studio.errors.InputError`; anything else (another exception type, a NumPy
RuntimeWarning such as an overflow or an invalid cast, a result that
breaks the reader's promises, a memory peak beyond the file's size) is a finding.
"""

from __future__ import annotations

import time
import tracemalloc
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from l2e_studio.errors import InputError

#: Memory a reader may trace for one case, beyond :data:`BYTES_PER_FILE_BYTE` per byte of the file.
BASE_BYTES = 48 * 2**20
#: Memory per byte of the file (decoded arrays are a few times larger than their bytes).
BYTES_PER_FILE_BYTE = 64


@dataclass(frozen=True)
class Target:
    """One reader under fuzz: a valid file's bytes, the suffix it needs, how to read it."""

    name: str
    suffix: str
    data: bytes
    load: Callable[[Path], object]
    check: Callable[[object], None] = lambda result: None
    lies: tuple[tuple[bytes, bytes], ...] = ()
    truncations: int = 200  # at most this many cut points, evenly spread (every offset of a smaller file)
    flips: int = 100


@dataclass
class Report:
    target: str
    cases: int = 0
    loaded: int = 0
    refused: int = 0
    seconds: float = 0.0
    peak_mb: float = 0.0
    findings: list[str] = field(default_factory=list)


def mutations(data: bytes, seed: int, flips: int, max_truncations: int,
              lies: tuple[tuple[bytes, bytes], ...] = ()) -> Iterator[tuple[str, bytes]]:
    """(label, damaged bytes): truncations (every offset, or ``max_truncations`` evenly spread),
    ``flips`` byte-flip cases, then each header lie."""
    step = max(1, len(data) // max_truncations)
    for cut in range(0, len(data), step):
        yield f"truncated at {cut}", data[:cut]
    rng = np.random.default_rng(seed)
    for i in range(flips):
        buf = bytearray(data)
        where = rng.integers(0, len(buf), int(rng.integers(1, 9)))
        for pos in where:
            buf[pos] = int(rng.integers(0, 256))
        yield f"flip #{i} at {sorted(int(w) for w in where)}", bytes(buf)
    for old, new in lies:
        assert old in data, f"header lie {old!r} not in the valid file"
        yield f"lie {old!r} -> {new!r}", data.replace(old, new, 1)


def run_target(target: Target, folder: Path, seed: int = 0) -> Report:
    """Every mutation of ``target.data`` written to ``folder/case<suffix>`` and read."""
    report = Report(target.name)
    path = folder / f"case{target.suffix}"
    target.check(target.load(_write(path, target.data)))  # the undamaged file reads and passes its check
    t0 = time.perf_counter()
    for label, data in mutations(target.data, seed, target.flips, target.truncations, target.lies):
        report.cases += 1
        _write(path, data)
        tracemalloc.start()
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error", RuntimeWarning)  # an overflow or a NaN cast is a finding too
                result = target.load(path)
            target.check(result)
            report.loaded += 1
        except InputError as exc:
            report.refused += 1
            line = str(exc)
            if "\n" in line or exc.path is None:
                report.findings.append(f"{label}: the error is not one line naming the file: {line!r}")
        except Exception as exc:  # noqa: BLE001 - a finding, reported with its type
            report.findings.append(f"{label}: {type(exc).__name__}: {str(exc)[:200]}")
        finally:
            peak = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
        report.peak_mb = max(report.peak_mb, peak / 2**20)
        if peak > BASE_BYTES + BYTES_PER_FILE_BYTE * len(data):
            report.findings.append(f"{label}: traced {peak / 2**20:.0f} MB for a {len(data)}-byte file")
    report.seconds = time.perf_counter() - t0
    return report


def _write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path
