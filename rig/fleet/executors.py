"""Where work on many recordings runs: a local process pool (the default, embedded), or a Dask cluster.

    for result in run_each(fit_one, paths, jobs=4):                       # this machine, 4 processes
    for result in run_each(fit_one, paths, scheduler="tcp://host:8786"):  # a dask.distributed cluster

Each item is one recording's work, independent of the others' (a path in, a few KB of results out), so it runs
unchanged on either; results come as they finish. The scheduler comes from `scheduler`, else the environment's
RIG_SCHEDULER, else none (the local pool). A cluster's workers read the recordings by the paths given, so the
files must be where the workers see them (a shared file system): docs/performance.md, "Past one machine".
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import socket
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any, TypeVar
from urllib.parse import urlsplit

T = TypeVar("T")
R = TypeVar("R")

SCHEDULER_ENV = "RIG_SCHEDULER"


def scheduler_address(given: str | None) -> str | None:
    """The Dask scheduler to use: `given`, else $RIG_SCHEDULER, else None (the local pool)."""
    return given or os.environ.get(SCHEDULER_ENV) or None


def run_each(fn: Callable[[T], R], items: Iterable[T], *, jobs: int | None = None,
             scheduler: str | None = None) -> Iterator[R]:
    """fn(item) for every item, as they finish: on the Dask cluster at `scheduler` (`scheduler_address`), else in
    `jobs` local processes (default: one per core; 1 runs them here, in order)."""
    items = list(items)
    address = scheduler_address(scheduler)
    if address:
        yield from _on_cluster(fn, items, address)
        return
    jobs = max(1, jobs or os.cpu_count() or 1)
    if jobs == 1 or len(items) <= 1:
        for item in items:
            yield fn(item)
        return
    with ProcessPoolExecutor(max_workers=min(jobs, len(items))) as pool:
        for f in as_completed([pool.submit(fn, item) for item in items]):
            yield f.result()


def _on_cluster(fn: Callable[[Any], R], items: list[Any], address: str) -> Iterator[R]:
    try:
        from distributed import Client
        from distributed import as_completed as finished
    except ImportError:
        raise ValueError(f"--scheduler {address}: running on a Dask cluster needs the distributed package; install it "
                         "with pip install 'rig[cluster]', or drop --scheduler (and unset RIG_SCHEDULER) to run here") from None
    try:
        _answers(address)
        client = Client(address, timeout="10s")
    except (OSError, TimeoutError) as e:
        raise ValueError(f"--scheduler {address}: no Dask scheduler answers there ({e}); start one (dask scheduler) or "
                         "check the address, or drop --scheduler (and unset RIG_SCHEDULER) to run here") from None
    with client:
        futures = client.map(_on_worker, [fn] * len(items), items, pure=False)
        for f in finished(futures):
            try:
                result = f.result()
            except (RuntimeError, ImportError, AttributeError) as e:  # the task could not be unpickled or run there
                why = str(e).splitlines()[0] if str(e) else type(e).__name__
                raise ValueError(f"--scheduler {address}: the cluster could not run rig's work ({why}); its scheduler "
                                 "and workers need the same rig as this machine (install it there, then restart them)") from None
            yield result


def _on_worker(fn: Callable[[Any], R], item: Any) -> R:
    """fn(item) on a Dask worker, with glibc's allocator as rig expects it (`_undo_trim_threshold`)."""
    _undo_trim_threshold()
    return fn(item)


_allocator_set = False


def _undo_trim_threshold() -> None:
    """A Dask nanny starts its workers with MALLOC_TRIM_THRESHOLD_=65536, which also fixes glibc's mmap threshold:
    then every array of a stop is mapped and unmapped afresh, and a fit of a full sweep spends 40 % more CPU in page
    faults (20 -> 28.5 s for four sweeps, measured with the local pool under the same setting). Once per worker
    process, where that variable is set: trim above 256 MB, map above 64 MB (a stop's arrays stay on the heap)."""
    global _allocator_set
    if _allocator_set or "MALLOC_TRIM_THRESHOLD_" not in os.environ:
        return
    _allocator_set = True
    try:

        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        libc.mallopt(-1, 256 << 20)  # M_TRIM_THRESHOLD
        libc.mallopt(-3, 64 << 20)  # M_MMAP_THRESHOLD
    except (OSError, AttributeError):
        pass


def _answers(address: str) -> None:
    """An OSError at once when nothing listens at a tcp:// address (Dask's own client retries for its whole timeout)."""

    where = urlsplit(address)
    if where.scheme == "tcp" and where.hostname and where.port:
        socket.create_connection((where.hostname, where.port), timeout=5).close()
