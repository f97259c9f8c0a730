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
