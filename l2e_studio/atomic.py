"""Writing files so that no reader, and no crash, ever sees half of one."""

from __future__ import annotations

import datetime as _dt
import errno
import os
import shutil
import stat
import tempfile
import time
from pathlib import Path

#: A temporary file without a live owner process older than this is litter from a killed write.
STALE_TMP_SECONDS = 3600.0


def atomic_write_bytes(path: str | Path, data: bytes, keep_existing: bool = False) -> Path | None:
    """Write ``data`` to ``path``: readers see the old file or the new one, never a part.

    The data goes to a temporary file in the same folder, is flushed to disk, and is renamed
    over ``path``. The new file gets the usual permissions (``0o666`` less the umask), not the
    owner-only ones of a temporary file. With ``keep_existing`` an existing file stays
    reachable under ``<stem>.<timestamp>.bak<suffix>``, which is returned.

    ``path`` must be a regular file or absent: a folder, device, FIFO, socket or symbolic link
    is never replaced (:class:`OSError`). Temporary files left by killed writes of the same
    ``path`` (their writer process is gone) are removed first.
    """
    path = Path(path)
    refuse_special(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    clean_stale_temporaries(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.{os.getpid()}.", suffix=".tmp", dir=path.parent)
    backup = None
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o666 & ~_umask())
        if keep_existing and path.exists():
            backup = backup_name(path)
            try:
                os.link(path, backup)  # the old content stays reachable under the backup name
            except OSError:  # no hard links on this file system
                shutil.copy2(path, backup)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return backup


def refuse_special(path: Path) -> None:
    """Raise :class:`OSError` unless ``path`` is absent or a regular file (not a link to one)."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    if stat.S_ISLNK(st.st_mode):
        raise OSError(errno.EEXIST, "is a symbolic link; give the path it points to", str(path))
    if stat.S_ISDIR(st.st_mode):
        raise IsADirectoryError(errno.EISDIR, "is a folder, not a file", str(path))
    if not stat.S_ISREG(st.st_mode):
        raise OSError(errno.EEXIST, "is a device, FIFO or socket, not a regular file", str(path))


def temporaries(path: Path) -> list[Path]:
    """The temporary files :func:`atomic_write_bytes` makes (or left) next to ``path``."""
    prefix = f".{path.name}."
    try:
        return [p for p in path.parent.iterdir() if p.name.startswith(prefix) and p.name.endswith(".tmp")]
    except OSError:
        return []


def clean_stale_temporaries(path: Path) -> list[Path]:
    """Remove temporaries of ``path`` whose writer is gone (killed mid-write); returns them.

    A temporary's name carries its writer's pid; one whose pid is not running, or that has no
    pid (older versions) and is over :data:`STALE_TMP_SECONDS` old, is litter.
    """
    removed = []
    prefix = f".{path.name}."
    for tmp in temporaries(path):
        owner = tmp.name[len(prefix):].split(".", 1)[0]
        if owner.isdigit():
            if int(owner) == os.getpid() or _alive(int(owner)):
                continue
        else:
            try:
                if time.time() - tmp.stat().st_mtime < STALE_TMP_SECONDS:
                    continue
            except OSError:
                continue
        try:
            tmp.unlink()
            removed.append(tmp)
        except OSError:
            pass
    return removed


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's live process
        return True
    return True


def backup_name(path: Path) -> Path:
    """A free ``<stem>.<YYYYmmdd-HHMMSS>[-n].bak<suffix>`` next to ``path``."""
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    suffix = "".join(path.suffixes)
    stem = path.name[: len(path.name) - len(suffix)] if suffix else path.name
    for i in range(1000):
        candidate = path.with_name(f"{stem}.{stamp}{'-' + str(i) if i else ''}.bak{suffix}")
        if not candidate.exists():
            return candidate
    raise FileExistsError(f"no free backup name for {path}")


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
