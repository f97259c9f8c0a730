"""``l2e-studio [serve]``: the browser workbench."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..scoring import EDGE_GRADIENTS, OBJECTIVES

#: Seconds a host name may take to resolve before --host is reported as unresolvable.
RESOLVE_TIMEOUT_S = 5.0
LOOPBACK = ("127.0.0.1", "localhost", "::1")

NAME = "serve"
HELP = "Serve the browser workbench (the default command): l2e-studio --scenes DIR"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scenes", type=Path, default=None,
                        help="scene folder (event/ + lidar/ + camera.yaml or config/config.json); "
                             "default: the embedded sample scenes")
    parser.add_argument("--host", default="127.0.0.1",
                        help="address to bind (default 127.0.0.1: this machine only; use SSH port forwarding "
                             "to reach it remotely)")
    parser.add_argument("--port", type=int, default=8080, help="port (default 8080)")
    parser.add_argument("--seed", type=Path, default=None, help="seed extrinsic file (overrides the folder's)")
    parser.add_argument("--camera", type=Path, default=None, help="intrinsics file (overrides the folder's)")
    parser.add_argument("--objective", choices=("auto", *OBJECTIVES), default="auto",
                        help="score read out and climbed: mi (event maps), edges (camera images); auto picks from the "
                             "map kind (default)")
    parser.add_argument("--edge-gradient", choices=EDGE_GRADIENTS, default="magnitude",
                        help="what the edge score reads in camera images: magnitude (default) or scan-lines (only the "
                             "gradient across the lidar's rings; see l2e-studio calibrate --help)")
    parser.add_argument("--map-kind", choices=("events", "image"),
                        help="treat every map as accumulated events or as a camera image (default: from file and content)")
    parser.add_argument("--out", type=Path, default=None,
                        help="folder for result and seed files (default: ./l2e_results/<scene folder name>; "
                             "never inside the scene folder unless given here; changeable in the app)")


def run(args: argparse.Namespace) -> int:
    from ..errors import InputError
    from ..samples import sample_scenes_dir
    from ..scenes import load_scene_folder

    if not 0 < args.port < 65536:
        raise InputError(None, f"--port must be 1..65535, got {args.port}")
    resolve_host(args.host)
    if args.out is not None:
        from .outputs import check_output_dir

        check_output_dir(args.out)
    folder = args.scenes if args.scenes is not None else sample_scenes_dir()
    print(f"Loading scenes from {folder} ...", flush=True)
    scene_set = load_scene_folder(folder, seed_file=args.seed, camera_file=args.camera, map_kind=args.map_kind)
    for failure in scene_set.failures:
        print(f"  scene {failure.name} not loaded: {failure.error}", file=sys.stderr)
    for note in scene_set.notes:
        print(f"  note: {note}", file=sys.stderr)
    print(f"  {len(scene_set.scenes)} scenes, camera {scene_set.camera.width}x{scene_set.camera.height}, "
          f"seed from {scene_set.seed_source}", flush=True)

    from ..app.server import serve

    def ready(app) -> None:
        port = app.server.get_port()
        if port != args.port:
            print(f"  port {args.port} is busy; serving on {port} instead", flush=True)
        print(f"L2E Studio is running at {app.url}  (Ctrl+C to stop)", flush=True)
        if args.host not in LOOPBACK:
            print(exposure_warning(args.host, port, out), file=sys.stderr, flush=True)
        if args.host in LOOPBACK:
            print(f"  remote machine? forward the port: ssh -L {port}:127.0.0.1:{port} <host>, "
                  f"then open http://127.0.0.1:{port}", flush=True)

    out = args.out if args.out is not None or args.scenes is not None else Path("l2e_results")
    try:
        serve(scene_set, host=args.host, port=args.port, out_dir=args.out, on_ready=ready, objective=args.objective,
              edge_gradient=args.edge_gradient)
    except OSError as exc:
        raise InputError(None, f"cannot serve on {args.host}:{args.port} ({exc.strerror or exc})") from None
    return 0


def resolve_host(host: str, timeout: float = RESOLVE_TIMEOUT_S) -> list[str]:
    """The addresses ``host`` resolves to; :class:`InputError` within ``timeout`` seconds otherwise."""
    import concurrent.futures
    import socket

    from ..errors import InputError

    pool = concurrent.futures.ThreadPoolExecutor(max_workers=1)
    try:
        infos = pool.submit(socket.getaddrinfo, host, None, 0, socket.SOCK_STREAM).result(timeout=timeout)
    except concurrent.futures.TimeoutError:
        raise InputError(None, f"--host {host!r} did not resolve within {timeout:g} s") from None
    except (socket.gaierror, UnicodeError, OSError) as exc:
        raise InputError(None, f"--host {host!r} does not resolve ({getattr(exc, 'strerror', None) or exc})") from None
    finally:
        pool.shutdown(wait=False)
    return sorted({info[4][0] for info in infos})


def exposure_warning(host: str, port: int, out: Path | None) -> str:
    """One line saying what binding to a non-loopback ``host`` exposes, with the URL others use."""
    import socket

    shown = host
    if host in ("0.0.0.0", "::", ""):  # every interface: show the address other machines route to
        shown = socket.gethostname()
        try:
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
                probe.connect(("192.0.2.1", 9))  # TEST-NET: nothing is sent, the kernel picks the interface
                shown = probe.getsockname()[0]
        except OSError:
            pass
    where = f" and can write files into {out}" if out is not None else ""
    return (f"warning: --host {host} exposes the workbench to the network: anyone who can reach "
            f"http://{shown}:{port} can use it{where}; prefer the default 127.0.0.1 with an SSH tunnel")
