"""Output paths given on the command line: checked before any work, and a result that cannot be
written is saved somewhere else (or printed) rather than lost."""

from __future__ import annotations

import datetime as _dt
import os
import stat
import sys
import tempfile
from pathlib import Path

from ..errors import InputError


def check_output_file(path: Path, option: str = "--out") -> Path:
    """Refuse an output file that is a folder, a device, FIFO or socket, or a symbolic link
    (links are not followed: give the target), or whose nearest existing parent is not a folder."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        st = None
    except OSError as exc:
        _check_parents(path, option)  # a parent that is a file (ENOTDIR) gets the clearer line
        raise InputError(path, f"{option} cannot be used ({exc.strerror or exc})") from None
    if st is not None:
        if stat.S_ISLNK(st.st_mode):
            raise InputError(path, f"{option} is a symbolic link (to {os.readlink(path)}); links are not followed, "
                                   "give the file it points to")
        if stat.S_ISDIR(st.st_mode):
            raise InputError(path, f"{option} is a folder; give a file name, e.g. {path / 'l2e_result.yaml'}")
        if not stat.S_ISREG(st.st_mode):
            raise InputError(path, f"{option} is a device, FIFO or socket, not a regular file")
    _check_parents(path, option)
    return path


def check_output_dir(path: Path, option: str = "--out") -> Path:
    """Refuse an output folder that exists as something else, or under a parent that is a file."""
    if path.exists() and not path.is_dir():
        raise InputError(path, f"{option} exists and is not a folder")
    _check_parents(path, option)
    return path


def _check_parents(path: Path, option: str) -> None:
    for parent in path.absolute().parents:
        if parent.exists():
            if not parent.is_dir():
                raise InputError(path, f"{option}: {parent} is a file, not a folder")
            return


def save_fallback(intended: Path, data: bytes) -> str:
    """Save ``data`` that could not go to ``intended``: a named file in the working folder, else in
    the temporary folder, else printed on stdout. Returns where it went, for the error line."""
    from ..atomic import atomic_write_bytes

    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    name = f"{intended.stem or 'l2e_result'}.unsaved-{stamp}-{os.getpid()}{intended.suffix or '.yaml'}"
    for folder in (Path.cwd(), Path(tempfile.gettempdir())):
        try:
            atomic_write_bytes(folder / name, data)
            return str(folder / name)
        except OSError:
            continue
    sys.stdout.write(data.decode("utf-8", "replace"))
    sys.stdout.flush()
    return "standard output (above)"
