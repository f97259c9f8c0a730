"""Writing files so that no reader, and no crash, ever sees half of one."""

from __future__ import annotations

import datetime as _dt
import os
import shutil
import tempfile
from pathlib import Path


def atomic_write_bytes(path: str | Path, data: bytes, keep_existing: bool = False) -> Path | None:
    """Write ``data`` to ``path``: readers see the old file or the new one, never a part.

    The data goes to a temporary file in the same folder, is flushed to disk, and is renamed
    over ``path``. The new file gets the usual permissions (``0o666`` less the umask), not the
    owner-only ones of a temporary file. With ``keep_existing`` an existing file stays
    reachable under ``<stem>.<timestamp>.bak<suffix>``, which is returned.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
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
