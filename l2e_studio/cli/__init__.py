"""The ``l2e-studio`` command.

``l2e-studio [--scenes DIR]`` (no sub-command) serves the browser workbench; the sub-commands
(``calibrate``, ``synth``, ``accumulate``, ``extract``) are headless. Each sub-command lives in a
module of this package exposing ``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``.
Bad input is reported as one line on stderr with exit status 2, never as a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from typing import Sequence

from ..errors import InputError

#: Sub-command modules, in the order ``--help`` lists them. "serve" is the default command.
COMMANDS: tuple[str, ...] = ("serve", "calibrate", "synth", "accumulate", "extract",
                             "heldout", "study", "landscape", "export", "report")
DEFAULT_COMMAND = "serve"


def _load_commands() -> dict:
    modules = {}
    for name in COMMANDS:
        try:
            modules[name] = importlib.import_module(f"{__name__}.{name}")
        except ModuleNotFoundError as exc:  # a command whose module is not there yet
            if exc.name != f"{__name__}.{name}":
                raise
    return modules


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="l2e-studio",
        description="Lidar to event-camera extrinsic calibration by mutual information. "
        "With no sub-command, serves the browser workbench.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, module in _load_commands().items():
        p = sub.add_parser(name, help=module.HELP, description=module.HELP)
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def _quiet_opencv() -> None:
    """OpenCV prints its own warnings for damaged images; we report them as one line instead."""
    import cv2.utils.logging

    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    known = set(parser._subparsers._group_actions[0].choices)  # type: ignore[union-attr]
    if not argv or (argv[0] not in known and argv[0] not in ("-h", "--help")):
        argv = [DEFAULT_COMMAND, *argv]
    args = parser.parse_args(argv)
    _quiet_opencv()  # after parsing: --help imports neither OpenCV nor numpy
    try:
        return int(args._run(args) or 0)
    except InputError as exc:
        print(f"l2e-studio: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # a file system refusal the command did not foresee: still one line
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"l2e-studio: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 2
    except MemoryError:
        print("l2e-studio: error: out of memory (the input is larger than this machine can hold)", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("l2e-studio: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
