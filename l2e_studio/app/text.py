"""How numbers read in the workbench: never "nan" (a missing value is "—")."""

from __future__ import annotations

import math

MISSING = "—"


def num(value: float | None, digits: int = 4, signed: bool = False) -> str:
    """``value`` with ``digits`` decimals, or "—" when it is None, NaN or infinite."""
    if value is None:
        return MISSING
    try:
        v = float(value)
    except (TypeError, ValueError):
        return MISSING
    if not math.isfinite(v):
        return MISSING
    return f"{v:+.{digits}f}" if signed else f"{v:.{digits}f}"


#: How each objective (``scoring.OBJECTIVES``) is named on screen.
SCORE_LABELS = {"mi": "MI", "edges": "edge score"}


def score_label(objective: str) -> str:
    """The on-screen name of an objective's score."""
    return SCORE_LABELS.get(objective, objective)


def score_num(value: float | None, signed: bool = False) -> str:
    """A score with 4 significant digits and at least 4 decimals (an edge score of 0.0026 reads
    0.002634, an MI of 0.41 reads 0.4123), or "—"; every score on screen goes through here."""
    if value is None or not math.isfinite(v := _float(value)):
        return MISSING
    digits = 4 if abs(v) >= 0.1 or v == 0 else min(10, 3 - math.floor(math.log10(abs(v))))
    return num(v, digits, signed)


def change(value: float | None, reference: float | None) -> str:
    """``value`` against ``reference`` as a relative change ("+26.4 %"), or "" when undefined."""
    if value is None or reference is None:
        return ""
    v, r = _float(value), _float(reference)
    if not (math.isfinite(v) and math.isfinite(r)) or r == 0:
        return ""
    return f"{100.0 * (v - r) / abs(r):+.1f} %"


def _float(value) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan
