"""``l2e-studio calibrate``: calibrate a folder of scenes end to end, headless."""

from __future__ import annotations

import argparse
import math
import re
import sys
import time
from pathlib import Path

from ..scoring import EDGE_GRADIENTS, OBJECTIVES
from ..errors import InputError
from .outputs import check_output_file, save_fallback

NAME = "calibrate"
HELP = "Calibrate the lidar-to-camera extrinsic of a scene folder (headless), with a verdict on the result."

#: The engine's optimisers and defaults, written out so that ``--help`` needs no numpy/scipy import
#: (tests/test_cli_inputs.py checks them against :mod:`l2e_studio.calibrate`).
METHODS = ("SLSQP", "L-BFGS-B", "Powell", "Nelder-Mead")
ON_UNTRUSTED = ("keep-seed", "mark")  # l2e_studio.verdict.ON_UNTRUSTED
DEFAULTS = {"translation_bound": 0.2, "rotation_bound_deg": 10.0, "sigma": 2.0}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenes", type=Path, help="scene folder (default: the embedded sample)")
    p.add_argument("--seed", type=Path, help="seed extrinsic file (overrides the folder's)")
    p.add_argument("--camera", type=Path, help="camera file (default: DIR/camera.yaml or DIR/config/config.json)")
    p.add_argument("--target", type=Path,
                   help="checkerboard file (target.yaml: kind, squares, square_m, size_m); calibrates from the board. "
                        "DIR/target.yaml is used when present")
    p.add_argument("--targetless", action="store_true",
                   help="climb the score even with a board in view, and check the result against the boards")
    p.add_argument("--out", type=Path, default=Path("l2e_result.yaml"),
                   help="result file, YAML or .json (default: ./l2e_result.yaml; an existing file is kept as a backup)")
    p.add_argument("--method", choices=METHODS, default="SLSQP", help="optimiser (default: SLSQP)")
    p.add_argument("--bound-m", type=float, default=DEFAULTS["translation_bound"],
                   help="translation bound per axis around the seed, metres (default: %(default)s)")
    p.add_argument("--bound-deg", type=float, default=DEFAULTS["rotation_bound_deg"],
                   help="rotation bound per axis around the seed, degrees (default: %(default)s)")
    p.add_argument("--sigma", type=float, default=DEFAULTS["sigma"],
                   help="event-map smoothing of the final stage, pixels (default: %(default)s)")
    p.add_argument("--objective", choices=("auto", *OBJECTIVES), default="auto",
                   help="score to climb: mi (the paper's, for event maps), edges (lidar edges on image edges, for "
                        "camera images); auto picks from the map kind (default)")
    p.add_argument("--edge-gradient", choices=EDGE_GRADIENTS, default="magnitude",
                   help="what the edge score reads in camera images: magnitude (every orientation, the default) or "
                        "scan-lines (only the gradient across the lidar's rings: stronger on sparse lidars with "
                        "several scenes, fooled more often where every scene shares a misleading structure)")
    p.add_argument("--map-kind", choices=("events", "image"),
                   help="treat every map as accumulated events or as a camera image (default: from file and content)")
    p.add_argument("--on-untrusted", choices=ON_UNTRUSTED, default="keep-seed",
                   help="when the verdict does not trust the result: keep the seed (default) or keep the result, marked")
    p.add_argument("--no-verdict", action="store_true", help="skip the verdict (the optimiser's answer is written as is)")
    p.add_argument("--rotation-only", action="store_true", help="keep the seed's translation, optimise rotation")
    p.add_argument("--single-stage", action="store_true", help="no coarse-to-fine schedule")
    p.add_argument("--check", action="store_true",
                   help="also probe the MI around the result and recalibrate on random halves of the scenes; "
                        "warns when an axis is flat or the answer moves with the scene subset")
    p.add_argument("--quiet", action="store_true", help="no progress display")


def run(args: argparse.Namespace) -> int:
    from rich.console import Console

    from ..atomic import atomic_write_bytes
    from ..calibrate import calibrate, stack_scenes
    from ..checks import check_seed_coverage
    from ..evaluate import assess
    from ..export import result_bytes
    from ..samples import sample_scenes_dir
    from ..scenes import load_scene_folder
    from ..verdict import judge

    err = Console(stderr=True)
    t_start = time.perf_counter()
    settings = _settings(args)
    folder = args.scenes or sample_scenes_dir()
    for path, what in ((args.seed, "seed file"), (args.camera, "camera file")):
        if path is not None and not path.is_file():
            raise InputError(path, f"{what} does not exist" if not path.exists() else f"{what} is not a regular file")
    check_output_file(args.out)
    from ._target import board_file, run_target

    board_path, board_how = board_file(args, folder)
    board = None
    if board_path is not None:
        from ..target import load_target

        board = load_target(board_path)  # a bad board file is one line before any loading

    with _progress(args.quiet, err) as prog:
        task = prog.add_task("loading scenes", total=None)
        scene_set = load_scene_folder(
            folder, args.seed, args.camera, map_kind=args.map_kind,
            on_scene=lambda i, n, name: prog.update(task, completed=i, total=n, description=f"loading {name}"),
        )
        prog.update(task, completed=prog.tasks[0].total or 1, description=f"loaded {len(scene_set.scenes)} scenes")
    for msg in scene_set.unpaired:
        print(f"warning: unpaired file {msg}", file=sys.stderr)
    for fail in scene_set.failures:
        print(f"warning: skipped scene {fail.name}: {fail.error}", file=sys.stderr)
    for note in scene_set.notes:
        print(f"note: {note}", file=sys.stderr)
    t_loaded = time.perf_counter()
    if board_path is not None and not args.targetless:
        return run_target(args, scene_set, board, board_path, board_how, t_start, t_loaded, _progress)

    seed = scene_set.seed
    check_seed_coverage([sc.points for sc in scene_set.scenes], scene_set.camera, seed, scene_set.seed_source)
    stack = stack_scenes(scene_set.scenes, scene_set.camera, seed, settings)
    with _progress(args.quiet, err) as prog:
        task = prog.add_task("optimising", total=1.0)

        def on_progress(p) -> None:
            prog.update(task, completed=p.fraction,
                        description=(f"{p.phase}  " if p.phase else "") + f"stage {p.stage + 1}/{p.stages}  eval {p.evaluations:4d}  {stack.objective_name} {p.best_mi:.5f}")

        result = calibrate(stack, None, seed, settings, on_progress=on_progress)
        prog.update(task, completed=1.0)

    failure = optimiser_failure(result)
    if failure:
        raise InputError(None, f"the optimiser failed ({failure}); no result was written")
    verdict = None
    if not args.no_verdict:
        with _progress(args.quiet, err) as prog:
            prog.add_task("judging the result (halves, second start, second score)", total=None)
            verdict = judge(stack, result, settings, on_untrusted=args.on_untrusted)
        if board is not None:
            verdict = _with_boards(verdict, scene_set, board, board_path, board_how, args)

    quality = None
    if args.check:
        with _progress(args.quiet, err) as prog:
            prog.add_task("checking the result on scene subsets", total=None)
            report = assess(stack, result.extrinsic, seed, settings)
        quality = report.to_dict()
        for line in report.warnings:
            print(f"warning: {line}", file=sys.stderr)
    console = Console()
    if not args.quiet:
        console.print(_summary(result, scene_set.seed))
    if verdict is not None:
        print("\n".join(verdict.lines()), flush=True)
    maps = {sc.name: sc.map_record() for sc in scene_set.scenes}
    data = result_bytes(args.out, result, scene_set.camera, scene_set.root, quality, verdict, maps)
    try:
        out, backup = args.out, atomic_write_bytes(args.out, data, keep_existing=True)
    except OSError as exc:
        where = save_fallback(args.out, data)
        raise InputError(args.out, f"cannot write the result ({exc.strerror or exc}); it was saved to {where}") from None
    console.print(f"result written to {out}" + (f" (previous file kept as {backup})" if backup else ""), highlight=False)
    console.print(
        f"{len(scene_set.scenes)} scenes, {stack.n_points} points; load {t_loaded - t_start:.2f} s, "
        f"optimisation {result.seconds:.2f} s ({result.evaluations} evaluations)"
        + (f", verdict {verdict.seconds:.2f} s" if verdict is not None else "")
        + f", total {time.perf_counter() - t_start:.2f} s",
        highlight=False,
    )
    return 0


def _with_boards(verdict, scene_set, board, board_path: Path, how: str, args):
    """The verdict with the boards in view as evidence the optimiser never climbed."""
    from rich.console import Console

    from ..target_verdict import with_boards

    print(f"note: the result is checked against the board in {board_path} (from {how})", file=sys.stderr)
    with _progress(args.quiet, Console(stderr=True)) as prog:
        prog.add_task("checking the result against the boards", total=None)
        return with_boards(verdict, scene_set.seed, scene_set.scenes, scene_set.camera, board,
                           on_untrusted=args.on_untrusted)


#: scipy messages of an optimiser that broke down (SLSQP modes 4-7, NaN objectives), as opposed
#: to one that stopped on a tolerance or an iteration limit.
FAILURE_MESSAGES = re.compile(r"incompatible|singular matrix|rank-deficient|\bnan\b|more equality constraints", re.I)


def optimiser_failure(result) -> str | None:
    """Why ``result`` is not a result (a non-finite score, a broken-down optimiser), or None."""
    if not (math.isfinite(result.score_result) and math.isfinite(result.score_seed)):
        return f"non-finite {result.objective} score: seed {result.score_seed}, result {result.score_result}"
    message = str(result.message or "")
    if FAILURE_MESSAGES.search(message):
        return message
    return None


def _settings(args: argparse.Namespace):
    """The engine's settings; bounds and sigma outside a sane range (or NaN) are refused here."""
    from ..calibrate import CalibrationSettings
    from ..limits import MAX_ROTATION_BOUND_DEG, MAX_SIGMA_PX, MAX_TRANSLATION_BOUND_M, require_range

    require_range("--bound-m", args.bound_m, 0.0, MAX_TRANSLATION_BOUND_M)
    require_range("--bound-deg", args.bound_deg, 0.0, MAX_ROTATION_BOUND_DEG, low_inclusive=False)
    require_range("--sigma", args.sigma, 0.0, MAX_SIGMA_PX)
    try:
        return CalibrationSettings(
            method=args.method,
            translation_bound=args.bound_m,
            rotation_bound_deg=args.bound_deg,
            sigma=args.sigma,
            rotation_only=args.rotation_only,
            coarse_to_fine=not args.single_stage,
            objective=args.objective,
            edge_gradient=args.edge_gradient,
        )
    except ValueError as exc:
        raise InputError(None, str(exc)) from None


def _progress(quiet: bool, console):
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    return Progress(
        TextColumn("{task.description}"), BarColumn(), TimeElapsedColumn(),
        console=console, disable=quiet or not console.is_terminal, transient=False,
    )


def _summary(result, seed):
    from rich.table import Table

    table = Table(title=f"L2E calibration ({result.objective} score)", show_lines=False)
    table.add_column("scene")
    table.add_column("score at seed", justify="right")
    table.add_column("score at result", justify="right")
    table.add_column("change", justify="right")
    for name, a, b in zip(result.scene_names, result.score_seed_per_scene, result.score_result_per_scene):
        table.add_row(name, f"{a:.4f}", f"{b:.4f}", f"{b - a:+.4f}")
    table.add_row("[b]all scenes[/]", f"[b]{result.score_seed:.4f}[/]", f"[b]{result.score_result:.4f}[/]",
                  f"[b]{result.score_result - result.score_seed:+.4f}[/]", end_section=True)
    from ..app.pose import sliders_from_extrinsic

    ext = result.extrinsic
    dr, dt = seed.error_to(ext)
    # the rotation as a correction to the seed (absolute roll/pitch/yaw of a lidar-camera rig sit
    # at gimbal lock, where a small correction reads as a large change; the result file has them)
    correction = sliders_from_extrinsic(ext, seed)[3:]
    table.caption = (
        f"t = [{', '.join(f'{v:.4f}' for v in ext.translation)}] m   "
        f"rotation correction to the seed (roll, pitch, yaw as the app's Seed sliders) = "
        f"[{', '.join(f'{v:+.3f}' for v in correction)}] deg   "
        f"moved {dr:.3f} deg / {100 * dt:.2f} cm from the seed"
        + ("   (cancelled)" if result.cancelled else "")
    )
    return table


