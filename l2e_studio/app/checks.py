"""Checks of what a person types into the optimiser and event-map settings (pure functions, no viser).

Nothing is clamped: a value outside its range is refused with a sentence that says why, shown
beside its field, and Start stays disabled until every field holds a meaningful value.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..io.events import Accumulation
from ..limits import MAX_ROTATION_BOUND_DEG, MAX_SIGMA_PX, MAX_TRANSLATION_BOUND_M  # the CLI's bounds
from .exact import parse_number

MAX_WINDOW_S = 3600.0  # an hour of a static scene is already far more than a map needs
MAX_HOT_PIXEL_SIGMA = 1000.0  # as the accumulate command's --hot-pixels
OFF_WORDS = ("", "off", "none", "no")
#: A seed's translation per axis, metres: the lidar must see what the camera sees, so the two sit
#: well within a lidar's range (~100 m for the usual spinning units); further, no point projects.
MAX_SEED_TRANSLATION_M = 100.0
#: A seed's roll / pitch / yaw correction, degrees: beyond half a turn an angle is the same
#: rotation as a smaller one the other way.
MAX_SEED_ANGLE_DEG = 180.0


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
        u = f" {unit}" if unit else ""
        why = f"{name}: {text.strip()}{u} is outside {bracket}{low:g}, {high:g}]{u}"
        return Checked(None, why + (f"; {hint}" if hint else ""))
    return Checked(value)


def check_translation_bound(text: str) -> Checked:
    """Metres either side of the start, per axis: [0, 5], as ``calibrate --bound-m`` (0: fixed)."""
    return _in_range(text, "± translation", "m", 0.0, MAX_TRANSLATION_BOUND_M, False,
                     "0 or Rotation only keeps the translation fixed")


def check_rotation_bound(text: str) -> Checked:
    """Degrees either side of the start, per axis: (0, 90], as ``calibrate --bound-deg``."""
    return _in_range(text, "± rotation", "°", 0.0, MAX_ROTATION_BOUND_DEG, True)


def check_sigma(text: str) -> Checked:
    """Gaussian smoothing of the maps in pixels: [0, 200], as ``calibrate --sigma`` (0: none)."""
    return _in_range(text, "Smoothing σ", "px", 0.0, MAX_SIGMA_PX, False)


def check_seed_value(text: str, axis: str, rotation: bool) -> Checked:
    """A typed seed value: translation within ±100 m, roll / pitch / yaw within ±180°."""
    if rotation:
        return _in_range(text, axis, "°", -MAX_SEED_ANGLE_DEG, MAX_SEED_ANGLE_DEG, False,
                         "a larger angle is the same rotation as a smaller one the other way")
    return _in_range(text, axis, "m", -MAX_SEED_TRANSLATION_M, MAX_SEED_TRANSLATION_M, False,
                     "lidar and camera must see the same scene")


def start_blocker(n_included: int, problems: list[str], running: bool, rebuilding: bool = False) -> str:
    """Why Start cannot run now ("" when it can)."""
    if running:
        return "a run is in progress"
    if rebuilding:
        return "event maps are being rebuilt (Scenes tab, Event map)"
    if n_included == 0:
        return "no scene is included: tick Use in optimisation for at least one scene (Scenes tab)"
    if problems:
        return "fix the settings marked above"
    return ""



@dataclass(frozen=True)
class AccumulationChecked:
    """The event-map fields as typed: the settings, or None with a problem per refused field."""

    settings: Accumulation | None
    problems: tuple[str, str, str]  # window, start, hot pixels ("" where fine)
    note: str = ""  # worth knowing, not a refusal


def check_accumulation(window: str, start: str, hot_pixels: str, duration_s: float | None) -> AccumulationChecked:
    """Check the three event-map fields against a recording ``duration_s`` long (None: unknown)."""
    w, s, h = check_window(window), check_start(start, duration_s), _check_hot_pixels(hot_pixels)
    problems = (w.problem, s.problem, h.problem)
    if not (w.ok and s.ok and h.ok):
        return AccumulationChecked(None, problems)
    hot = None if h.value == float("inf") else h.value
    settings = Accumulation(window_s=float(w.value), start_s=float(s.value), hot_pixel_sigma=hot)
    return AccumulationChecked(settings, problems, window_note(settings.start_s, settings.window_s, duration_s))


def check_window(text: str) -> Checked:
    """Accumulation window in seconds: (0, 3600]."""
    return _in_range(text, "Window", "s", 0.0, MAX_WINDOW_S, True)


def check_start(text: str, duration_s: float | None) -> Checked:
    """Seconds into the recording: [0, duration) when the duration is known, else >= 0."""
    value = parse_number(text)
    if value is None:
        return Checked(None, f"Start: “{text}” is not a number")
    if value < 0:
        return Checked(None, f"Start: {text.strip()} s is before the recording; it starts at 0 s")
    if duration_s is not None and value >= duration_s:
        return Checked(None, f"Start: {text.strip()} s is past the end of the recording ({duration_s:.3f} s long)")
    return Checked(value)


def _check_hot_pixels(text: str) -> Checked:
    """Hot-pixel suppression: ``off`` (value ``inf`` here: nothing is suppressed) or a sigma in (0, 1000]."""
    if str(text).strip().lower() in OFF_WORDS:
        return Checked(float("inf"))
    if parse_number(text) is None:
        return Checked(None, f"Hot-pixel σ: “{text}” is neither a number nor off")
    return _in_range(text, "Hot-pixel σ", "", 0.0, MAX_HOT_PIXEL_SIGMA, True, "type off to keep every pixel")


def window_note(start: float, window: float, duration_s: float | None) -> str:
    """What a window that runs past the end of the recording counts ("" when it does not)."""
    if duration_s is None or start + window <= duration_s:
        return ""
    return (f"the window ends {start + window - duration_s:.3g} s after the recording: "
            f"it counts the last {duration_s - start:.3g} s")
