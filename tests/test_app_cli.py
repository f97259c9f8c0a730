"""``l2e-studio [serve]``: serves the workbench on 127.0.0.1 and prints the URL; bad input is
one line and exit status 2."""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

from app_fixtures import free_port, write_small_scenes
from l2e_studio.cli import main

REPO = Path(__file__).resolve().parents[1]


def test_missing_scene_folder_is_one_line_and_status_2(tmp_path, capsys):
    assert main(["--scenes", str(tmp_path / "nope"), "--port", str(free_port())]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nope" in err[0] and "does not exist" in err[0]


def test_folder_without_scenes_is_rejected(tmp_path, capsys):
    (tmp_path / "event").mkdir()
    assert main(["serve", "--scenes", str(tmp_path), "--port", str(free_port())]) == 2
    assert "no scene found" in capsys.readouterr().err


@pytest.mark.parametrize("which", ["given", "embedded sample"])
def test_serve_prints_the_url_binds_loopback_and_serves_the_page(tmp_path, which):
    port = free_port()
    cmd = [sys.executable, "-m", "l2e_studio", "--port", str(port), "--out", str(tmp_path / "out")]
    if which == "given":
        cmd += ["--scenes", str(write_small_scenes(tmp_path / "scenes", n_scenes=2))]
    elif not (REPO / "assets" / "sample").is_dir():
        pytest.skip("assets/sample is not in this checkout")
    # Ctrl-C as a user's terminal delivers it, however the suite was started (a background job of
    # a non-interactive shell ignores SIGINT, its children inherit that, and Python then installs
    # no KeyboardInterrupt handler)
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        lines = []
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            lines.append(line)
            if "forward the port" in line:
                break
        url = f"http://127.0.0.1:{port}"
        assert any(url in line and "running at" in line for line in lines), "".join(lines)
        if which == "embedded sample":
            assert any(str(REPO / "assets" / "sample") in line for line in lines)
        assert any(f"ssh -L {port}:127.0.0.1:{port}" in line for line in lines)
        with urllib.request.urlopen(url, timeout=10) as response:
            assert response.status == 200
            assert b"<html" in response.read(4096).lower()
        if shutil.which("ss"):  # the listening socket is on the loopback address only
            listening = subprocess.run(["ss", "-Hltn", f"sport = :{port}"], capture_output=True, text=True)
            local = [row.split()[3] for row in listening.stdout.splitlines() if row.strip()]
            assert local and all(addr == f"127.0.0.1:{port}" for addr in local), listening.stdout
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130


def test_build_app_defaults_to_loopback(tmp_path):
    from l2e_studio.app.server import build_app
    from l2e_studio.scenes import load_scene_folder

    scene_set = load_scene_folder(write_small_scenes(tmp_path / "s", n_scenes=1))
    app = build_app(scene_set, port=free_port())
    try:
        assert app.server.get_host() == "127.0.0.1"
        assert app.url.startswith("http://127.0.0.1:")
        assert app.out_dir == Path.cwd() / "l2e_results" / scene_set.root.name  # never inside the data
    finally:
        app.stop()


@pytest.mark.parametrize("args", [["--port", "0"], ["--port", "70000"]])
def test_bad_port_is_rejected(args, capsys):
    assert main(["--scenes", "unused", *args]) == 2
    assert "--port" in capsys.readouterr().err


def test_busy_port_moves_to_a_free_one_and_says_so(tmp_path, capsys, monkeypatch):
    import socket
    import threading

    import l2e_studio.app.server as server_module

    real_serve = server_module.serve
    seen = {}

    def serve_until_ready(scene_set, host, port, out_dir, on_ready, **kw):
        stop = threading.Event()

        def ready(app):
            seen["port"] = app.server.get_port()
            on_ready(app)
            stop.set()

        real_serve(scene_set, host, port, out_dir, on_ready=ready, stop=stop, **kw)

    monkeypatch.setattr(server_module, "serve", serve_until_ready)
    scenes = write_small_scenes(tmp_path / "scenes", n_scenes=1)
    with socket.socket() as blocker:
        blocker.bind(("127.0.0.1", 0))
        blocker.listen()
        busy = blocker.getsockname()[1]
        assert main(["--scenes", str(scenes), "--port", str(busy), "--out", str(tmp_path / "o")]) == 0
    out = capsys.readouterr().out
    assert seen["port"] != busy
    assert f"port {busy} is busy; serving on {seen['port']}" in out
    assert f"ssh -L {seen['port']}:127.0.0.1:{seen['port']}" in out
