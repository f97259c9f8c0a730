"""The report's verdict reads as a headline in words with its checks as a table, and a landscape
guardrail that seems to contradict the verdict's single-peak check says what each measures."""

from __future__ import annotations

import numpy as np

from l2e_studio.qa import guardrails
from l2e_studio.qa.landscape import Sweep1D
from l2e_studio.qa.report import guardrail_notes, verdict_html

ROTATION = {
    "status": "trusted-rotation",
    "summary": "rotation trusted; the translation is not pinned down by these scenes, the seed's translation is kept",
    "kept_seed": False,
    "reasons": ["halves agree (translation): refined on either half alone the translation moves 4.0 cm (limit 3)"],
    "checks": {"score": {"passed": True, "detail": "edges score 0.0021 -> 0.0026"},
               "halves agree (translation)": {"passed": False, "detail": "moves 4.0 cm (limit 3)"},
               "a single peak": {"passed": True, "detail": "no other start ended near its score"}},
    "seconds": 6.2,
}


def test_verdict_is_a_headline_in_words_with_a_table_of_checks():
    page = verdict_html(ROTATION)
    assert "ROTATION TRUSTED, translation not: the seed&#x27;s translation is handed back" in page
    assert "class='warn'" in page and "SEED&#x27;s translation, not calibrated" in page
    assert "<td>halves agree (translation)</td><td>FAILED</td>" in page
    assert "<td>score</td><td>passed</td>" in page
    assert '"status"' not in page and "{" not in page  # no raw JSON dump
    assert "NOT JUDGED" in verdict_html(None) and "no <code>verdict:</code> section" in verdict_html(None)
    assert "class='bad'" in verdict_html({"status": "not-trusted", "kept_seed": True, "reasons": ["x"]})


def test_a_confirmed_seed_is_the_headline():
    v = {"status": "trusted", "kept_seed": False, "reasons": [],
         "summary": "the seed stands, confirmed: the seed's rotation stands (the result turned 0.05 deg from it, "
                    "within 2x the 0.13 deg its independent estimates spread)",
         "within_spread": {"rotation_from_seed": True, "translation_from_seed": ["x", "y", "z"],
                           "note": "the seed's rotation stands (the result turned 0.05 deg from it)"},
         "spread": {"rotation_deg": 0.13, "translation_m": 0.007}, "seed_stands": True,
         "checks": {"score": {"passed": True, "detail": "up"}}}
    page = verdict_html(v)
    assert "SEED CONFIRMED" in page and "class='ok'" in page
    assert "SEED&#x27;s values stand" in page and "0.05 deg" in page


def test_a_second_bump_on_a_sweep_is_told_apart_from_the_single_peak_check():
    offs = np.linspace(-0.05, 0.05, 21)
    vals = np.exp(-(offs / 0.01) ** 2) + 0.96 * np.exp(-((offs - 0.04) / 0.005) ** 2)  # a side bump at +4 cm
    warns = guardrails.flat_landscape([Sweep1D("y", offs, vals)], "edge score")
    assert [w.code for w in warns] == ["ambiguous"]
    assert "1-D sweep of the edge score along y" in warns[0].message and "+-0.05 m" in warns[0].message
    notes = guardrail_notes(warns, ROTATION)
    assert len(notes) == 1 and "'a single peak'" in notes[0] and "1-D sweep" in notes[0]
    failed = {**ROTATION, "checks": {"a single peak": {"passed": False, "detail": ""}}}
    assert guardrail_notes(warns, failed) == []  # they agree: nothing to reconcile
