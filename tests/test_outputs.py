"""Writers: special files are never replaced, killed writes leave the old or the new complete file,
and their temporary files are removed by the next write."""

from __future__ import annotations

import os
import signal
import stat
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from l2e_studio.atomic import atomic_write_bytes, clean_stale_temporaries, temporaries
from l2e_studio.cli.outputs import check_output_file, save_fallback
from l2e_studio.errors import InputError

#: A child that starts an atomic write of ``sys.argv[1]`` and hangs before the rename (in fsync).
_HANGING_WRITER = textwrap.dedent("""
    import os, sys, time
    from l2e_studio import atomic
    os.fsync = lambda fd: time.sleep(60)
    atomic.atomic_write_bytes(sys.argv[1], b"new complete content\\n" * 1000)
""")


def _killed_write(path: Path) -> None:
    proc = subprocess.Popen([sys.executable, "-c", _HANGING_WRITER, str(path)])
    deadline = time.monotonic() + 30
    while not any(t.stat().st_size > 0 for t in temporaries(path)):
        assert time.monotonic() < deadline and proc.poll() is None, "the writer never started"
        time.sleep(0.02)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()


def test_kill_9_leaves_the_old_file_and_the_next_write_cleans_up(tmp_path: Path) -> None:
    path = tmp_path / "result.yaml"
    path.write_text("old\n")
    for _ in range(3):
        _killed_write(path)  # each writer first removes the litter of the one killed before it
        assert path.read_text() == "old\n"
        assert len(temporaries(path)) == 1
    atomic_write_bytes(path, b"newer\n")
    assert path.read_text() == "newer\n" and temporaries(path) == []


def test_live_and_unrelated_temporaries_are_kept(tmp_path: Path) -> None:
    path = tmp_path / "a.yaml"
    live = tmp_path / f".a.yaml.{os.getppid()}.x.tmp"  # our parent is alive
    fresh_legacy = tmp_path / ".a.yaml.abcdef.tmp"  # no pid, young: maybe a running old version
    other = tmp_path / ".b.yaml.1.x.tmp"
    for f in (live, fresh_legacy, other):
        f.write_text("x")
    old_legacy = tmp_path / ".a.yaml.zzzzzz.tmp"
    old_legacy.write_text("x")
    os.utime(old_legacy, (time.time() - 7200, time.time() - 7200))
    assert clean_stale_temporaries(path) == [old_legacy]
    assert live.exists() and fresh_legacy.exists() and other.exists()


@pytest.mark.parametrize("kind", ["folder", "fifo", "symlink", "device"])
def test_atomic_write_never_replaces_a_special_file(tmp_path: Path, kind: str) -> None:
    path = tmp_path / "x"
    if kind == "folder":
        path.mkdir()
    elif kind == "fifo":
        os.mkfifo(path)
    elif kind == "symlink":
        (tmp_path / "target").write_text("keep")
        path.symlink_to(tmp_path / "target")
    else:  # a private copy of /dev/null's device: a regression replaces it, never the real one
        try:
            os.mknod(path, stat.S_IFCHR | 0o666, os.makedev(1, 3))
        except PermissionError:
            pytest.skip("creating a device node needs root")
    before = os.lstat(path)
    with pytest.raises(OSError):
        atomic_write_bytes(path, b"data")
    after = os.lstat(path)
    assert (before.st_mode, before.st_ino) == (after.st_mode, after.st_ino)
    assert not any(p.name.endswith(".tmp") for p in path.parent.iterdir())


def test_check_output_file_accepts_new_and_regular_files(tmp_path: Path) -> None:
    assert check_output_file(tmp_path / "new" / "deeper" / "r.yaml")
    (tmp_path / "r.yaml").write_text("x")
    assert check_output_file(tmp_path / "r.yaml")
    with pytest.raises(InputError, match="folder"):
        check_output_file(tmp_path)


def test_fallback_goes_to_the_working_folder(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    where = save_fallback(Path("/nowhere/res.json"), b"{}\n")
    assert Path(where).parent == tmp_path and where.endswith(".json") and Path(where).read_bytes() == b"{}\n"


def test_synth_and_write_lidar_txt_write_atomically(tmp_path: Path, monkeypatch) -> None:
    """Both scan writers go through the atomic writer (a full disk never leaves half a scan)."""
    from l2e_studio import atomic
    from l2e_studio.io.lidar import load_lidar, write_lidar_txt
    from l2e_studio.synth import SynthConfig, config_with, write_dataset

    written: list[str] = []
    real = atomic.atomic_write_bytes

    def spy(path, data, keep_existing=False):
        written.append(Path(path).name)
        return real(path, data, keep_existing)

    for module in ("l2e_studio.synth.dataset", "l2e_studio.io.lidar"):
        monkeypatch.setattr(f"{module}.atomic_write_bytes", spy)
    write_dataset(tmp_path / "s", config_with(SynthConfig(), n_scenes=1, width=160, height=90, points_per_scan=500))
    assert {"scene_000.txt", "scene_000.png", "camera.yaml", "truth.yaml", "config.json"} <= set(written)
    pts = np.random.default_rng(0).normal(size=(10, 3)) + [0, 0, 5]
    write_lidar_txt(tmp_path / "c.txt", pts, np.arange(10.0))
    assert written[-1] == "c.txt" and len(load_lidar(tmp_path / "c.txt")) == 10


def test_every_writer_goes_through_the_atomic_writer() -> None:
    """No module writes a user-visible file directly (a full disk or a kill would leave half of it);
    the one exception is the app's private temporary copy of an upload."""
    import re

    root = Path(__file__).resolve().parents[1] / "l2e_studio"
    direct = re.compile(r"\.write_(text|bytes)\(|cv2\.imwrite\(|np\.save(txt)?\((?!buf)|open\([^)]*['\"][wa]b?['\"]")
    allowed = {("app/files.py", "path.write_bytes(content)")}
    hits = []
    for path in root.rglob("*.py"):
        rel = path.relative_to(root).as_posix()
        if rel == "atomic.py":
            continue
        for line in path.read_text().splitlines():
            if direct.search(line) and (rel, line.strip()) not in allowed:
                hits.append(f"{rel}: {line.strip()}")
    assert hits == []
