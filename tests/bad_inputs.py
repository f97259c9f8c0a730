"""Running the real CLI on a bad input: exit status, stderr lines and the child's peak memory."""

from __future__ import annotations

import os
import signal
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


#: A small launcher between pytest and the CLI. A child forked straight from pytest counts the
#: test process's pages in its peak RSS (Linux records the old address space's high-water mark
#: at exec), so the number grew with whatever ran before; forked from this launcher, the CLI's
#: peak is its own (plus the launcher's few MB). The launcher caps the address space, runs the
#: CLI, and reports its peak RSS (kB) as the last line of its own stdout.
LAUNCHER = """
import os, resource, sys
cap = int(sys.argv[1])
pid = os.fork()
if pid == 0:
    resource.setrlimit(resource.RLIMIT_AS, (cap, cap))
    os.execv(sys.executable, [sys.executable, "-m", "l2e_studio", *sys.argv[2:]])
_, status, usage = os.wait4(pid, 0)
sys.stdout.flush()
os.write(1, f"\\n@@peak_rss_kb {usage.ru_maxrss}\\n".encode())
sys.exit(os.waitstatus_to_exitcode(status))
"""


def run_cli(*args, cwd: Path | None = None, timeout: float = 120, stdin: str | None = None) -> CliRun:
    """``python -m l2e_studio ARGS`` with capped address space; its own peak RSS (see LAUNCHER)."""
    env = {**os.environ, "COLUMNS": "200", "PYTHONUNBUFFERED": "1"}
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-c", LAUNCHER, str(CHILD_ADDRESS_SPACE), *map(str, args)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL,
                            cwd=cwd, env=env, start_new_session=True)
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)  # the launcher and the CLI under it
        proc.communicate()
        raise TimeoutError(f"l2e-studio {' '.join(map(str, args))} ran past {timeout} s") from None
    stdout, _, tail = out.rpartition("\n@@peak_rss_kb ")
    if not tail:
        raise RuntimeError(f"the launcher reported no peak RSS: {err[-500:]}")
    return CliRun(proc.returncode, stdout, err, int(tail.split()[0]) / 1024, time.perf_counter() - t0)


def assert_one_line_error(run: CliRun, *fragments: str) -> str:
    """Exit 2, exactly one stderr line, no traceback, every fragment in that line."""
    assert "Traceback" not in run.stderr, run.stderr
    assert run.returncode == 2, (run.returncode, run.stderr)
    assert len(run.error_lines) == 1, run.stderr
    line = run.error_lines[0]
    for frag in fragments:
        assert str(frag) in line, (frag, line)
    return line
