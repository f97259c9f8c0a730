"""Where L2E Studio keeps its caches: the user's cache folder, never the data folder.

``$XDG_CACHE_HOME/l2e-studio`` (``~/.cache/l2e-studio`` when the variable is unset). Caches
are rebuilt when missing, so the folder can be deleted at any time.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path


def user_cache_dir(*parts: str) -> Path:
    """``$XDG_CACHE_HOME/l2e-studio/<parts...>`` (not created here)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "l2e-studio" / Path(*parts) if parts else Path(base) / "l2e-studio"


def folder_key(folder: str | Path) -> str:
    """A short, stable name for a data folder (its resolved path, hashed) inside the cache."""
    resolved = str(Path(folder).resolve())
    return f"{Path(resolved).name}-{hashlib.sha1(resolved.encode()).hexdigest()[:12]}"
