"""The real-data benchmark's verdict-stability tools: a nudged seed is the seed turned by exactly
the nudge about an axis fixed per run, and two saved runs compare run by run."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bench_realdata import flips, host, nudged  # noqa: E402
from realdata_rigs import Rig, split  # noqa: E402

from l2e_studio.camera import CameraModel  # noqa: E402
from l2e_studio.geometry import Extrinsic  # noqa: E402
from l2e_studio.scenes import Scene  # noqa: E402


def test_a_nudge_turns_the_seed_by_itself_about_an_axis_fixed_per_run():
    seed = Extrinsic(np.array([0.1, -0.2, 0.3]), np.array([0.5, 0.0, -0.1]))
    assert nudged(seed, 3, 0.0) is seed
    a, b, c = nudged(seed, 3, 1e-3), nudged(seed, 3, 1e-3), nudged(seed, 4, 1e-3)
    assert np.allclose(a.matrix, b.matrix, rtol=0, atol=0)  # the same in every invocation
    deg, m = seed.error_to(a)
    assert abs(deg - 1e-3) < 1e-9 and m == 0.0
    assert a.error_to(c)[0] > 1e-4  # another run, another axis


def row(status, cls, opt_deg, rig="r", level="1deg/5cm"):
    return dict(rig=rig, level=level, variant="new", status=status, cls=cls, opt_deg=opt_deg, opt_m=0.01)


def test_flips_counts_verdicts_that_differ_run_by_run():
    a = [row("trusted-rotation", "closer", 0.2), row("not-trusted", "kept", 0.2), row("trusted-rotation", "worse", 1.6),
         row("not-trusted", "kept", 3.0)]
    b = [row("not-trusted", "kept", 0.21), row("not-trusted", "kept", 0.2), row("trusted-rotation", "worse", 1.6),
         row("trusted-rotation", "closer", 0.9)]
    text = flips(a, b)
    assert "| r | 1deg/5cm | 4 | 2 | 1 | 1 / 1 |" in text  # two flipped, one at the same optimiser end
    assert text.splitlines()[-1] == "| all | | 4 | 2 | 1 | |"


def test_flips_say_when_the_two_ran_on_different_hosts():
    here = host()
    cpu, blas, simd = here.split("; ")  # the CPU and the kernels that round a climb
    assert cpu and blas != "no BLAS" and simd.startswith("numpy ")
    a = [dict(row("trusted-rotation", "closer", 0.2), host=here)]
    assert flips(a, [dict(r) for r in a]).splitlines()[-1].startswith("| all |")  # one host: nothing said
    text = flips(a, [dict(a[0], host="another CPU; openblas SkylakeX; numpy AVX512_SKX")])
    assert text.splitlines()[-1].startswith("ran on different hosts") and "SkylakeX" in text and here in text


def test_split_makes_every_k_scans_a_rig_of_their_own():
    camera = CameraModel(np.array([[100.0, 0, 32], [0, 100.0, 24], [0, 0, 1]]), 64, 48)
    reference = Extrinsic(np.zeros(3), np.array([0.1, 0.0, 0.0]))
    scenes = tuple(Scene(f"s{i}", np.full((5, 3), float(i)), np.zeros(5), np.zeros((48, 64), np.float32)) for i in range(5))
    rigs = split([Rig("drive", camera, reference, scenes), Rig("one", camera, reference, scenes[:1])])
    assert [r.name for r in rigs] == ["drive/s0", "drive/s1", "drive/s2", "drive/s3", "drive/s4", "one/s0"]
    assert all(len(r.scenes) == 1 and r.camera is camera and r.reference is reference for r in rigs)
    assert [r.scenes[0].points[0, 0] for r in rigs] == [0.0, 1.0, 2.0, 3.0, 4.0, 0.0]
    pairs = split([Rig("drive", camera, reference, scenes), Rig("one", camera, reference, scenes[:1])], 2)
    assert [r.name for r in pairs] == ["drive/s0+1", "drive/s2+1"]  # the short last group and rig are dropped
    assert [[s.name for s in r.scenes] for r in pairs] == [["s0", "s1"], ["s2", "s3"]]
