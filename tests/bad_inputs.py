"""Running the real CLI on a bad input: exit status, stderr lines and the child's peak memory."""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

#: Address-space cap for a child: a memory bomb fails fast instead of swapping the machine.
CHILD_ADDRESS_SPACE = 6 * 2**30


@dataclass
class CliRun:
    returncode: int
    stdout: str
    stderr: str
    peak_rss_mb: float
    seconds: float

    @property
    def error_lines(self) -> list[str]:
        return [ln for ln in self.stderr.splitlines() if ln.strip()]


def run_cli(*args, cwd: Path | None = None, timeout: float = 120, stdin: str | None = None) -> CliRun:
    """``python -m l2e_studio ARGS`` in a child with capped address space; peak RSS from ``wait4``."""

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (CHILD_ADDRESS_SPACE, CHILD_ADDRESS_SPACE))

    env = {**os.environ, "COLUMNS": "200", "PYTHONUNBUFFERED": "1"}
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-m", "l2e_studio", *map(str, args)], stdout=out, stderr=err,
                                stdin=subprocess.DEVNULL, cwd=cwd, env=env, preexec_fn=limit)
        deadline = t0 + timeout
        while True:
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                break
            if time.perf_counter() > deadline:
                proc.kill()
                _, status, usage = os.wait4(proc.pid, 0)
                raise TimeoutError(f"l2e-studio {' '.join(map(str, args))} ran past {timeout} s")
            time.sleep(0.02)
        proc.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        err.seek(0)
        return CliRun(proc.returncode, out.read(), err.read(), usage.ru_maxrss / 1024, time.perf_counter() - t0)


def assert_one_line_error(run: CliRun, *fragments: str) -> str:
    """Exit 2, exactly one stderr line, no traceback, every fragment in that line."""
    assert "Traceback" not in run.stderr, run.stderr
    assert run.returncode == 2, (run.returncode, run.stderr)
    assert len(run.error_lines) == 1, run.stderr
    line = run.error_lines[0]
    for frag in fragments:
        assert str(frag) in line, (frag, line)
    return line
