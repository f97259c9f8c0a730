"""``l2e-studio calibrate`` with a checkerboard: the target method's run, table and verdict lines."""

from __future__ import annotations

import sys
import time
from pathlib import Path

from ..errors import InputError
from .outputs import save_fallback


def board_file(args, folder: Path) -> tuple[Path | None, str]:
    """The board file to use (``--target``, else the scene folder's target.yaml) and how it was found."""
    from ..target import find_target

    if args.target is not None:
        if not args.target.is_file():
            raise InputError(args.target, "target file does not exist" if not args.target.exists()
                             else "target file is not a regular file")
        return args.target, "--target"
    found = find_target(folder)
    return found, "the scene folder"


def run_target(args, scene_set, board, board_path: Path, how: str, t_start: float, t_loaded: float, progress) -> int:
    """The checkerboard method on the loaded scenes with ``board`` (read from ``board_path``)."""
    from rich.console import Console

    from ..atomic import atomic_write_bytes
    from ..export import result_bytes
    from ..target import calibrate_target
    from ..target_verdict import judge_target

    print(f"note: checkerboard calibration with the board in {board_path} (from {how}): {board.squares[0]}x"
          f"{board.squares[1]} squares of {1000 * board.square_m:g} mm, {board.size_m[0]:g} x {board.size_m[1]:g} m",
          file=sys.stderr)
    err = Console(stderr=True)
    names = ("detecting the board in the images", "finding the board in the scans", "solving")
    with progress(args.quiet, err) as prog:
        task = prog.add_task(names[0], total=1.0)

        def on_progress(p) -> None:
            extra = f"  board RMS {-p.best_mi:.1f} mm" if p.best_mi == p.best_mi else ""
            prog.update(task, completed=p.fraction, description=names[p.stage] + extra)

        result = calibrate_target(scene_set.scenes, scene_set.camera, scene_set.seed, board, on_progress=on_progress)
        prog.update(task, completed=1.0)
    verdict = None if args.no_verdict else judge_target(result, on_untrusted=args.on_untrusted)
    console = Console()
    if not args.quiet:
        console.print(_table(result))
    for f in result.target.frames:
        if not f.used:
            print(f"warning: frame {f.name} left out: {f.reason}", file=sys.stderr)
    if verdict is not None:
        print("\n".join(verdict.lines()), flush=True)
    maps = {sc.name: sc.map_record() for sc in scene_set.scenes}
    data = result_bytes(args.out, result, scene_set.camera, scene_set.root, None, verdict, maps)
    try:
        backup = atomic_write_bytes(args.out, data, keep_existing=True)
    except OSError as exc:
        where = save_fallback(args.out, data)
        raise InputError(args.out, f"cannot write the result ({exc.strerror or exc}); it was saved to {where}") from None
    console.print(f"result written to {args.out}" + (f" (previous file kept as {backup})" if backup else ""), highlight=False)
    d = result.target
    console.print(f"{len(d.frames)} frames, board detected in {sum(f.detected for f in d.frames)}, used "
                  f"{len(d.used)}; load {t_loaded - t_start:.2f} s, detection {d.seconds['detection']:.2f} s, "
                  f"lidar {d.seconds['lidar']:.2f} s, solve {d.seconds['solve']:.2f} s, "
                  f"total {time.perf_counter() - t_start:.2f} s", highlight=False)
    return 0


def _table(result):
    from rich.table import Table

    d = result.target
    table = Table(title="L2E checkerboard calibration", show_lines=False)
    for col, j in (("frame", "left"), ("corners", "left"), ("reproj px", "right"), ("lidar pts", "right"),
                   ("plane mm", "right"), ("edge mm", "right"), ("left out: moves", "right"), ("used", "left")):
        table.add_column(col, justify=j)
    mm = lambda v: "—" if v != v else f"{1000 * v:.1f}"  # noqa: E731
    for f in d.frames:
        table.add_row(f.name, _detector(f.detection.method) if f.detected else "not found",
                      "—" if not f.detected else f"{f.detection.reprojection_px:.2f}", str(f.lidar.n_points),
                      mm(f.plane_rms_m), mm(f.edge_rms_m),
                      "—" if f.loo_m != f.loo_m else f"{1000 * f.loo_m:.1f} mm/{f.loo_deg:.2f}°",
                      "yes" if f.used else "no")
    ext = result.extrinsic
    dr, dt = result.seed.error_to(ext)
    s_m, s_d = d.sigma_m, d.sigma_deg
    table.caption = (
        f"t = [{', '.join(f'{v:.4f}' for v in ext.translation)}] m   "
        f"rpy = [{', '.join(f'{v:.3f}' for v in ext.rpy())}] deg   moved {dr:.3f} deg / {100 * dt:.2f} cm from the seed\n"
        f"sigma x, y, z = {', '.join(f'{1000 * v:.1f}' for v in s_m)} mm   rx, ry, rz = "
        f"{', '.join(f'{v:.3f}' for v in s_d)} deg   board RMS {-result.score_seed:.1f} mm at the seed -> "
        f"{-result.score_result:.1f} mm" + ("   (cancelled)" if result.cancelled else ""))
    return table


def _detector(method: str) -> str:
    """A short name of the detector that found the corners (the result file has the full one)."""
    if "SB" in method:
        return "sector"
    return "quad 2x" if "x2" in method else "quad"
