"""Exact numbers by hand: parse what a person types or pastes, format values without losing
digits, and centre slider ranges on the current value (pure functions, no viser).

Values are never rounded to a slider grid: a typed ``-0.1234`` stays ``-0.1234``, and a slider
whose range is centred on the current value moves it by whole steps from there.
"""

from __future__ import annotations

import math
import re

#: How many steps a slider spans either side of its centre (so its range narrows with the step).
SLIDER_HALF_STEPS = 100
#: Rotation sliders never span more than this either side of their centre (deg).
MAX_HALF_RANGE_DEG = 90.0

_PARTIAL = re.compile(r"^\s*[-+]?(\d*\.?\d*)?([eE][-+]?)?\s*$")


def parse_number(text: str) -> float | None:
    """The finite number in ``text`` (``-0.1234``, ``+1e-3``, `` 0,5 ``), or None.

    A decimal comma is accepted; NaN, infinities and anything else give None.
    """
    cleaned = str(text).strip().replace(",", ".").replace("−", "-")
    if not cleaned:
        return None
    try:
        value = float(cleaned)
    except ValueError:
        return None
    return value if math.isfinite(value) else None


def is_partial(text: str) -> bool:
    """True for text on its way to a number ("", "-", "0.", "1e-"): not worth a complaint."""
    cleaned = str(text).strip().replace(",", ".").replace("−", "-")
    return parse_number(cleaned) is None and bool(_PARTIAL.match(cleaned))


def format_value(value: float, decimals: int = 6) -> str:
    """``value`` with up to ``decimals`` decimals and no trailing zeros (``-0.1234``, ``0``)."""
    text = f"{float(value):.{decimals}f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def nudged(value: float, delta: float) -> float:
    """``value + delta``, nothing else: the digits a value had below the step are kept."""
    return float(value) + float(delta)


def centred_range(value: float, step: float, rotation: bool = False) -> tuple[float, float]:
    """A slider range of :data:`SLIDER_HALF_STEPS` steps either side of ``value``."""
    half = SLIDER_HALF_STEPS * float(step)
    if rotation:
        half = min(half, MAX_HALF_RANGE_DEG)
    return float(value) - half, float(value) + half
