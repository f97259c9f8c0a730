"""``l2e-studio synth``: write synthetic scenes with a known true extrinsic."""

from __future__ import annotations

import argparse
from pathlib import Path


NAME = "synth"
HELP = ("Write synthetic scenes (lidar scans + event maps, or checkerboard sequences with --target) with a known "
        "true extrinsic (truth.yaml).")

#: the camera kinds ``--target`` renders (:data:`l2e_studio.synth.board_views.MODALITIES`).
MODALITIES = ("frame", "e2vid", "events", "events-moving")

#: full: :class:`~l2e_studio.synth.SynthConfig`'s defaults; sample: ``SAMPLE_CONFIG`` (imported when run).
PRESETS = ("full", "sample")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=Path, required=True, help="output folder (must be empty or new, unless --force)")
    p.add_argument("--preset", choices=PRESETS, default="full",
                   help="full: the paper's sensors, 40 scenes (default); sample: 6 small scenes as in assets/")
    p.add_argument("--scenes", type=int, help="number of scenes (full: 40)")
    p.add_argument("--width", type=int, help="event-map width in pixels (full: 1280)")
    p.add_argument("--height", type=int, help="event-map height in pixels (default: width x 9/16)")
    p.add_argument("--points", type=int, help="lidar points per scan (full: 75000)")
    p.add_argument("--seed", type=int, help="random seed: same seed, same dataset (full: 0)")
    p.add_argument("--seed-error-deg", type=float, help="rotation error of the written seed extrinsic (default: 2)")
    p.add_argument("--seed-error-m", type=float, help="translation error of the written seed extrinsic (default: 0.05)")
    p.add_argument("--no-distortion", action="store_true", help="an ideal pinhole camera (default: small radtan distortion)")
    p.add_argument("--camera-image", action="store_true",
                   help="write grey camera images (under image/) instead of accumulated event maps")
    p.add_argument("--realism", action="store_true",
                   help="reproduce real data's failure modes: shading, saturated sky, unrelated texture, foliage and a "
                        "lidar beam 3 mrad wide for camera images; range fall-off, flickering lamps, blooming, hot "
                        "pixels and an occluded band for event maps")
    p.add_argument("--traps", help="only some failure modes, comma-separated (see --realism)")
    p.add_argument("--dim", action="store_true", help="a dim cloud: intensities 0..14 (the sparse-cloud trap)")
    p.add_argument("--lidar", choices=("vlp16", "hdl32", "hdl64", "os128"),
                   help="a spinning lidar's rings and azimuth step: Velodyne VLP-16, HDL-32E, HDL-64E, Ouster "
                        "OS1-128 (garage scenes: within the 120 deg view, instead of the MEMS raster and --points; "
                        "--target: default vlp16)")
    board = p.add_argument_group("checkerboard sequences (--target checkerboard)")
    board.add_argument("--target", choices=("checkerboard",),
                       help="a board held up at a different pose in each scene (10 scenes, 10 x 7 squares of 68 mm), "
                            "seen by a 16-beam lidar; target.yaml and each board's true pose are written too")
    board.add_argument("--modality", choices=MODALITIES,
                       help="frame: a 1280x720 frame camera; e2vid: 346x260 images reconstructed from events (blur, "
                            "noise, low contrast); events: event map of a flashing board; events-moving: of a shaken "
                            "board (default: frame)")
    board.add_argument("--lens", choices=("radtan", "equidistant"), help="lens distortion model (default: radtan)")
    board.add_argument("--range-noise-m", type=float, help="lidar range noise (sigma, default 0.015 m)")
    p.add_argument("--force", action="store_true", help="write into a non-empty folder (old scene_* files are removed)")
    p.add_argument("--quiet", action="store_true", help="no progress display")


def config_from_args(args: argparse.Namespace):
    """The :class:`SynthConfig` the command line asks for (raises ValueError when out of range)."""
    from ..synth import SAMPLE_CONFIG, SynthConfig, config_with

    if args.lidar is not None and args.points is not None:
        raise ValueError("--points sets the MEMS raster's size; a --lidar's rings and azimuth step set their own")
    base = SAMPLE_CONFIG if args.preset == "sample" else SynthConfig()
    height = args.height
    if args.width is not None and height is None:
        height = max(16, round(args.width * 9 / 16))
    config = config_with(base, n_scenes=args.scenes, width=args.width, height=height, points_per_scan=args.points,
                         seed=args.seed, seed_error_deg=args.seed_error_deg, seed_error_m=args.seed_error_m)
    if args.no_distortion:
        config = config_with(config, distortion=False)
    traps = tuple(t.strip() for t in args.traps.split(",") if t.strip()) if args.traps else None
    return config_with(config, map_kind="image" if args.camera_image else None, realism=args.realism or None,
                       traps=traps, intensity_scale=0.055 if args.dim else None, lidar=args.lidar)


#: options that shape the garage scenes only (refused with --target).
_GARAGE_ONLY = ("preset", "points", "realism", "traps", "dim", "camera_image", "no_distortion")


def target_config_from_args(args: argparse.Namespace):
    """The :class:`~l2e_studio.synth.TargetConfig` of ``--target`` (ValueError when out of range)."""
    from ..synth import TargetConfig, target_config_with

    given = [name for name in _GARAGE_ONLY if getattr(args, name) not in (None, False, "full")]
    if given:
        raise ValueError(f"--{given[0].replace('_', '-')} shapes the garage scenes, not --target sequences")
    if (args.width is None) != (args.height is None):
        raise ValueError("give both --width and --height with --target")
    return target_config_with(TargetConfig(), modality=args.modality, lens=args.lens, n_scenes=args.scenes,
                              width=args.width, height=args.height, seed=args.seed,
                              seed_error_deg=args.seed_error_deg, seed_error_m=args.seed_error_m,
                              range_noise_m=args.range_noise_m, lidar=args.lidar)


def run(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    from ..synth import check_out_dir, make_rig, make_target_rig, write_dataset, write_target_dataset
    from .outputs import check_output_dir

    err = Console(stderr=True)
    try:
        board_only = [f"--{n.replace('_', '-')}" for n in ("modality", "lens", "range_noise_m") if getattr(args, n) is not None]
        if board_only and not args.target:
            raise ValueError(f"{board_only[0]} needs --target checkerboard")
        config = target_config_from_args(args) if args.target else config_from_args(args)
    except ValueError as exc:
        err.print(f"l2e-studio synth: error: {exc}", highlight=False)
        return 2
    check_output_dir(args.out)
    check_out_dir(args.out, args.force)
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
               TimeRemainingColumn())
    with Progress(*columns, console=err, disable=args.quiet, transient=False) as prog:
        task = prog.add_task(f"writing {config.n_scenes} scenes", total=config.n_scenes)
        write = write_target_dataset if args.target else write_dataset
        out = write(args.out, config, on_scene=lambda done, total: prog.update(task, completed=done),
                    overwrite=args.force)
    _, truth, seed = make_target_rig(config) if args.target else make_rig(config)
    deg, m = seed.error_to(truth)
    if not args.quiet:
        what = (f"{config.modality} board scenes ({'x'.join(map(str, config.size))})" if args.target else f"scenes ({config.width}x{config.height}, ~{config.points_per_scan} points)")
        board_file = f"\n  board: {out / 'target.yaml'}" if args.target else ""
        seed_files = out / "camera.yaml" if args.target else f"{out / 'camera.yaml'} and {out / 'config' / 'config.json'}"
        Console().print(
            f"wrote {config.n_scenes} {what} to "
            f"{out}\n  truth: {out / 'truth.yaml'}{board_file}\n  seed ({deg:.2f} deg, {m * 100:.1f} cm from the truth): {seed_files}",
            highlight=False,
        )
    return 0
