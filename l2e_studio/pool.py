"""The engine's worker threads, shared by the objective and the map preparation.

numpy and OpenCV release the GIL inside their loops, so independent slices of one evaluation
(chunks of points, one map each) really run at once on the threads of one small pool.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Sequence

#: Threads per process (``L2E_THREADS``); the QA studies set 1 in each worker process.
WORKERS = int(os.environ.get("L2E_THREADS", min(4, os.cpu_count() or 1)))
CHUNK = 65536  # points per work item: a chunk's temporaries stay in cache
_POOL: ThreadPoolExecutor | None = None


def _pool() -> ThreadPoolExecutor:
    global _POOL
    if _POOL is None:
        _POOL = ThreadPoolExecutor(WORKERS, thread_name_prefix="l2e-objective")
    return _POOL


def run_chunks(work: Callable[[int, int], None], n: int) -> None:
    """Call ``work(a, b)`` over ``[0, n)`` in chunks, on the worker threads when there are several.

    Each call writes its own slice of the output arrays, so the chunks need no locking.
    """
    run_tasks(lambda ab: work(*ab), [(a, min(a + CHUNK, n)) for a in range(0, n, CHUNK)])


def run_tasks(work: Callable, items: Sequence) -> None:
    """Call ``work(item)`` for every item, on the worker threads when there are several."""
    items = list(items)
    if WORKERS > 1 and len(items) > 1:
        for f in [_pool().submit(work, item) for item in items]:
            f.result()
    else:
        for item in items:
            work(item)
