"""Checks of what a person types into the optimiser settings (pure functions, no viser).

Nothing is clamped: a value outside its range is refused with a sentence that says why, shown
beside its field, and Start stays disabled until every field holds a meaningful value.
"""

from __future__ import annotations

from dataclasses import dataclass

from .exact import parse_number

MAX_TRANSLATION_BOUND_M = 2.0
MAX_ROTATION_BOUND_DEG = 45.0
MAX_SIGMA_PX = 50.0


@dataclass(frozen=True)
class Checked:
    """A field's value, or the reason it was refused (``value`` is None then)."""

    value: float | None
    problem: str = ""

    @property
    def ok(self) -> bool:
        return self.value is not None


def _in_range(text: str, name: str, unit: str, low: float, high: float, low_open: bool, hint: str = "") -> Checked:
    value = parse_number(text)
    if value is None:
        return Checked(None, f"{name}: “{text}” is not a number")
    too_low = value <= low if low_open else value < low
    if too_low or value > high:
        bracket = "(" if low_open else "["
        why = f"{name}: {text.strip()} {unit} is outside {bracket}{low:g}, {high:g}] {unit}"
        return Checked(None, why + (f"; {hint}" if hint else ""))
    return Checked(value)


def check_translation_bound(text: str) -> Checked:
    """Metres either side of the start, per axis: (0, 2]."""
    return _in_range(text, "± translation", "m", 0.0, MAX_TRANSLATION_BOUND_M, True,
                     "tick Rotation only to keep the translation fixed")


def check_rotation_bound(text: str) -> Checked:
    """Degrees either side of the start, per axis: (0, 45]."""
    return _in_range(text, "± rotation", "°", 0.0, MAX_ROTATION_BOUND_DEG, True)


def check_sigma(text: str) -> Checked:
    """Gaussian smoothing of the maps in pixels: (0, 50]."""
    return _in_range(text, "Smoothing σ", "px", 0.0, MAX_SIGMA_PX, True)


def start_blocker(n_included: int, problems: list[str], running: bool) -> str:
    """Why Start cannot run now ("" when it can)."""
    if running:
        return "a run is in progress"
    if n_included == 0:
        return "no scene is included: tick Use in optimisation for at least one scene (Scenes tab)"
    if problems:
        return "fix the settings marked above"
    return ""
