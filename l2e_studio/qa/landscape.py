"""The MI landscape around an extrinsic: 1-D sweeps along each of the six parameters and a 2-D
sweep of any two, to show how sharp and unambiguous the optimum is.

Offsets are a local correction of the centre (camera frame): metres for ``x, y, z``, degrees
for ``rx, ry, rz``. The score is the paper's MI of all scenes pooled at the stack's smoothing.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..errors import InputError
from ..geometry import Extrinsic
from ..objective import SceneStack
from . import AXES


def axis_index(name: str | int) -> int:
    if isinstance(name, int) or str(name).isdigit():
        k = int(name)
    else:
        aliases = {"roll": "rx", "pitch": "ry", "yaw": "rz"}
        k = AXES.index(aliases.get(str(name), str(name))) if aliases.get(str(name), str(name)) in AXES else -1
    if not 0 <= k < 6:
        raise InputError(None, f"unknown axis {name!r}; expected one of {', '.join(AXES)}")
    return k


def _offset(centre: Extrinsic, k: int, v: float) -> Extrinsic:
    d = np.zeros(6)
    d[k] = v if k < 3 else np.radians(v)
    return centre.perturbed(d[:3], d[3:])


@dataclass
class Sweep1D:
    axis: str
    offsets: np.ndarray  # m or deg
    mi: np.ndarray

    @property
    def peak_offset(self) -> float:
        return float(self.offsets[int(np.nanargmax(self.mi))])

    def half_width(self) -> float:
        """Half the width of the region around the peak where the MI stays above halfway
        between its peak and the sweep's minimum (in the axis' unit): small = sharp."""
        i = int(np.nanargmax(self.mi))
        half = 0.5 * (np.nanmax(self.mi) + np.nanmin(self.mi))
        lo = i
        while lo > 0 and self.mi[lo - 1] >= half:
            lo -= 1
        hi = i
        while hi < len(self.mi) - 1 and self.mi[hi + 1] >= half:
            hi += 1
        return float(0.5 * (self.offsets[hi] - self.offsets[lo]))

    def secondary_ratio(self) -> float:
        """Height of the best other local maximum relative to the peak, both above the sweep's
        minimum (0 = a single peak, near 1 = ambiguous)."""
        m = self.mi
        base = np.nanmin(m)
        i = int(np.nanargmax(m))
        peaks = [j for j in range(1, len(m) - 1) if m[j] >= m[j - 1] and m[j] >= m[j + 1] and abs(j - i) > 1]
        peaks += [j for j in (0, len(m) - 1) if abs(j - i) > 1 and m[j] > m[j + (1 if j == 0 else -1)]]
        if not peaks or m[i] <= base:
            return 0.0
        return float(max((m[j] - base) / (m[i] - base) for j in peaks))

    def to_dict(self) -> dict:
        return {"axis": self.axis, "unit": "m" if self.axis in AXES[:3] else "deg", "offsets": self.offsets.tolist(),
                "mi": [round(float(v), 6) for v in self.mi], "peak_offset": self.peak_offset,
                "half_width": self.half_width(), "secondary_ratio": round(self.secondary_ratio(), 4)}


@dataclass
class Sweep2D:
    axes: tuple[str, str]
    offsets: tuple[np.ndarray, np.ndarray]
    mi: np.ndarray  # (len(offsets[0]), len(offsets[1]))

    def to_dict(self) -> dict:
        return {"axes": list(self.axes), "offsets": [o.tolist() for o in self.offsets],
                "mi": np.round(self.mi, 6).tolist()}


def default_span(k: int, span_m: float, span_deg: float) -> float:
    return span_m if k < 3 else span_deg


def sweep1d(stack: SceneStack, centre: Extrinsic, axis: str | int, span: float, n: int = 21,
            cancel: threading.Event | None = None) -> Sweep1D:
    k = axis_index(axis)
    if n < 3 or not span > 0:
        raise InputError(None, f"a sweep needs >= 3 steps and a positive span, got n={n}, span={span}")
    offs = np.linspace(-span, span, n)
    vals = np.full(n, np.nan)
    for i, v in enumerate(offs):
        if cancel is not None and cancel.is_set():
            break
        vals[i] = stack.score(_offset(centre, k, v), per_scene=False)[0]
    return Sweep1D(AXES[k], offs, vals)


def sweeps(stack: SceneStack, centre: Extrinsic, span_m: float = 0.05, span_deg: float = 2.0, n: int = 21,
           on_progress: Callable[[int, int], None] | None = None, cancel: threading.Event | None = None) -> list[Sweep1D]:
    """One 1-D sweep along each of the six axes."""
    out = []
    for k in range(6):
        out.append(sweep1d(stack, centre, k, default_span(k, span_m, span_deg), n, cancel))
        if on_progress is not None:
            on_progress(k + 1, 6)
    return out


def sweep2d(stack: SceneStack, centre: Extrinsic, axis_a: str | int, axis_b: str | int, span_a: float, span_b: float,
            n: int = 15, cancel: threading.Event | None = None) -> Sweep2D:
    a, b = axis_index(axis_a), axis_index(axis_b)
    if a == b:
        raise InputError(None, "a 2-D sweep needs two different axes")
    oa, ob = np.linspace(-span_a, span_a, n), np.linspace(-span_b, span_b, n)
    vals = np.full((n, n), np.nan)
    for i, va in enumerate(oa):
        for j, vb in enumerate(ob):
            if cancel is not None and cancel.is_set():
                return Sweep2D((AXES[a], AXES[b]), (oa, ob), vals)
            d = np.zeros(6)
            d[a] = va if a < 3 else np.radians(va)
            d[b] = vb if b < 3 else np.radians(vb)
            vals[i, j] = stack.score(centre.perturbed(d[:3], d[3:]), per_scene=False)[0]
    return Sweep2D((AXES[a], AXES[b]), (oa, ob), vals)
