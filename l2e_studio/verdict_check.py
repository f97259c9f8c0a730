"""One piece of evidence on a calibration result: its name, whether it passed, and why (in words).

Shared by every judge (:mod:`l2e_studio.verdict`, :mod:`l2e_studio.peaks`,
:mod:`l2e_studio.target_verdict`), so the result file, exports and report read them alike.
(:mod:`l2e_studio.checks` holds the checks of inputs, before any calibration.)"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Check:
    name: str
    passed: bool
    detail: str
