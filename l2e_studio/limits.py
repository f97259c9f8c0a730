"""Sane ranges for user-supplied numbers, shared by the readers, the CLI and the app.

Outside these ranges an input cannot inform a calibration (or would only exhaust memory), so it
is refused with one line instead of producing a silent wrong result.
"""

from __future__ import annotations

import math

from .errors import InputError

#: Image / sensor side, pixels. The largest event sensors are 1280x720; frame cameras used as
#: stand-ins stay far below this. A header or camera file claiming more is refused.
MAX_IMAGE_SIDE = 16_384
#: Event sensor side, pixels, when a recording states no size (the largest sensors are 1280x720):
#: a grid grown to the coordinates seen stops here instead of allocating gigabytes.
MAX_EVENT_SENSOR_SIDE = 4096
#: Event times may step back this much (microseconds; decoder jitter) and are still handled;
#: a larger backward step means the recording is not time-ordered, and is refused.
MAX_BACKWARD_STEP_US = 1000
#: A rotation block R is accepted when max |R^T R - I| and |det R - 1| are within this.
ROTATION_TOLERANCE = 1e-3
#: Translation bound per axis, metres: a lidar-camera rig is at most a few metres across.
MAX_TRANSLATION_BOUND_M = 5.0
#: Rotation bound per axis, degrees (the parametrisation is a correction of the seed).
MAX_ROTATION_BOUND_DEG = 90.0
#: Final-stage map smoothing, pixels; wider only costs memory (1e6 px asked for 8.7 GiB).
MAX_SIGMA_PX = 200.0


#: Longest event accumulation window and latest start, seconds (a day: anything more is a typo).
MAX_WINDOW_S = 86_400.0


def require_range(option: str, value: float | None, low: float, high: float, low_inclusive: bool = True) -> None:
    """Raise :class:`InputError` naming ``option`` unless ``value`` (None: not given) is finite and
    within ``[low, high]`` (``(low, high]`` when not ``low_inclusive``)."""
    if value is None:
        return
    ok = math.isfinite(value) and (value >= low if low_inclusive else value > low) and value <= high
    if not ok:
        raise InputError(None, f"{option} must be a finite number in {'[' if low_inclusive else '('}{low:g}, {high:g}], "
                               f"got {value:g}")
