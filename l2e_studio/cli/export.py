"""``l2e-studio export``: a result (or any seed file) in other formats, each labelled with its direction."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..errors import InputError

NAME = "export"
HELP = ("Write a calibration as 4x4 text, ROS 1/ROS 2 static_transform_publisher, URDF joint, Kalibr YAML, YAML or "
        "JSON, each stating the result's verdict (for trusted-rotation: that the translation is the seed's).")
#: The engine's export formats, written out so that ``--help`` needs no engine import
#: (tests/test_packaging.py checks them against :data:`l2e_studio.export.EXPORT_FORMATS`).
FORMAT_NAMES = ("yaml", "json", "matrix", "ros1", "ros2", "urdf", "kalibr")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", type=Path, help="result file (or any file --seed reads)")
    p.add_argument("--format", action="append", default=[], metavar="FMT",
                   help=f"one of {', '.join(FORMAT_NAMES)}, or 'all'; repeatable (default: all)")
    p.add_argument("--out", type=Path, help="output file (one format) or folder (several); default: print to stdout")
    p.add_argument("--camera-frame", default="camera", help="camera frame / link name (default: %(default)s)")
    p.add_argument("--lidar-frame", default="lidar", help="lidar frame / link name (default: %(default)s)")
    p.add_argument("--require-trusted", action="store_true",
                   help="refuse (exit 2, nothing written) unless the result's verdict is 'trusted': for pipelines "
                        "that must not ship a seed's translation (trusted-rotation) or an unjudged result")


def run(args: argparse.Namespace) -> int:
    from ..export import EXPORT_FORMATS, export_status, export_text
    from ..io.cameras import load_seed
    from ._qa_common import check_writable, read_doc, write

    fmts: list[str] = []
    for f in args.format or ["all"]:
        for name in f.split(","):
            if name == "all":
                fmts += list(EXPORT_FORMATS)
            elif name not in EXPORT_FORMATS:
                raise InputError(None, f"unknown export format {name!r}; expected one of {', '.join(EXPORT_FORMATS)}, all")
            else:
                fmts.append(name)
    fmts = list(dict.fromkeys(fmts))
    ext = load_seed(args.input)
    result = None
    if args.input.suffix.lower() in (".yaml", ".yml", ".json"):
        try:
            doc = read_doc(args.input)
            result = doc if "T_cam_lidar" in doc else None
        except InputError:
            result = None
    status, notes = export_status(result)
    if args.require_trusted and status != "trusted":
        raise InputError(args.input, f"the verdict is '{status}', not 'trusted' (--require-trusted); nothing written")
    texts = {f: export_text(ext, f, args.camera_frame, args.lidar_frame, result=result) for f in fmts}
    if args.out is None:
        for f, t in texts.items():
            if len(texts) > 1:
                print(f"# ---- {f} ----")
            sys.stdout.write(t)
        return 0
    if len(fmts) == 1 and args.out.suffix:
        targets = {fmts[0]: args.out}
    else:
        targets = {f: args.out / f"T_cam_lidar{EXPORT_FORMATS[f]}" for f in fmts}
    for path in targets.values():
        check_writable(path)
    for f, path in targets.items():
        backup = write(path, texts[f].encode())
        print(f"{f}: {path}" + (f" (previous file kept as {backup})" if backup else ""))
    for line in notes:
        print(line)
    return 0
