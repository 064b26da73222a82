"""Where work on many recordings runs: a local process pool (the default, embedded), or a Dask cluster.

    for result in run_each(fit_one, paths, jobs=4):                       # this machine, 4 processes
    for result in run_each(fit_one, paths, scheduler="tcp://host:8786"):  # a dask.distributed cluster

Each item is one recording's work, independent of the others' (a path in, a few KB of results out), so it runs
unchanged on either; results come as they finish. The scheduler comes from `scheduler`, else the environment's
RIG_SCHEDULER, else none (the local pool). A cluster's workers read the recordings by the paths given, so the
files must be where the workers see them (a shared file system), by absolute paths (`rig.fleet.many.portable`):
docs/performance.md, "Past one machine". A cluster with no worker for `timeout_s` seconds, at the start or after
its last worker is lost, ends the run with a one-line `NoWorkers` (the results yielded before it stand).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import os
import queue
import socket
import time
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from typing import Any, TypeVar
from urllib.parse import urlsplit

T = TypeVar("T")
R = TypeVar("R")

SCHEDULER_ENV = "RIG_SCHEDULER"

#: how long a run on a cluster waits, with no worker there, for one to join (--timeout), s
DEFAULT_TIMEOUT_S = 60.0


class NoWorkers(ValueError):
    """The cluster had no worker for the whole timeout: none joined, or the last one was lost and none came back."""

    def __init__(self, message: str, done: int, total: int):
        super().__init__(message)
        self.done, self.total = done, total


def scheduler_address(given: str | None) -> str | None:
    """The Dask scheduler to use: `given`, else $RIG_SCHEDULER, else None (the local pool)."""
    return given or os.environ.get(SCHEDULER_ENV) or None


def run_each(fn: Callable[[T], R], items: Iterable[T], *, jobs: int | None = None,
             scheduler: str | None = None, timeout_s: float | None = None) -> Iterator[R]:
    """fn(item) for every item, as they finish: on the Dask cluster at `scheduler` (`scheduler_address`), else in
    `jobs` local processes (default: one per core; 1 runs them here, in order). On a cluster, `NoWorkers` once it
    has had no worker for `timeout_s` seconds (default: DEFAULT_TIMEOUT_S)."""
    items = list(items)
    address = scheduler_address(scheduler)
    if address:
        yield from _on_cluster(fn, items, address, DEFAULT_TIMEOUT_S if timeout_s is None else timeout_s)
        return
    jobs = max(1, jobs or os.cpu_count() or 1)
    if jobs == 1 or len(items) <= 1:
        for item in items:
            yield fn(item)
        return
    with ProcessPoolExecutor(max_workers=min(jobs, len(items))) as pool:
        for f in as_completed([pool.submit(fn, item) for item in items]):
            yield f.result()


def _on_cluster(fn: Callable[[Any], R], items: list[Any], address: str, timeout_s: float) -> Iterator[R]:
    try:
        from distributed import Client
    except ImportError:
        raise ValueError(f"--scheduler {address}: running on a Dask cluster needs the distributed package; install it "
                         "with pip install 'rig[cluster]', or drop --scheduler (and unset RIG_SCHEDULER) to run here") from None
    try:
        _answers(address)
        client = Client(address, timeout="10s")
    except (OSError, TimeoutError) as e:
        raise ValueError(f"--scheduler {address}: no Dask scheduler answers there ({e}); start one (dask scheduler) or "
                         "check the address, or drop --scheduler (and unset RIG_SCHEDULER) to run here") from None
    with _quiet(logging.getLogger("distributed.client")), client:
        futures = client.map(_on_worker, [fn] * len(items), items, pure=False)
        yield from _as_they_finish(client, futures, address, timeout_s)


@contextmanager
def _quiet(logger: logging.Logger) -> Iterator[None]:
    """`logger` silent inside: the client logs its failed reconnections, with tracebacks, when the scheduler goes
    away, and rig says so in one line (`_as_they_finish`)."""
    level = logger.level
    logger.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        logger.setLevel(level)


def _as_they_finish(client: Any, futures: list[Any], address: str, timeout_s: float) -> Iterator[Any]:
    """The futures' results as they come. Between results the scheduler is asked for its workers (every `poll_s`);
    none there for `timeout_s` seconds is `NoWorkers`: Dask itself waits for ever, its tasks in the "no-worker" state."""
    from distributed import CancelledError

    finished: queue.SimpleQueue = queue.SimpleQueue()  # futures as they finish (or fail, or are cancelled)
    for f in futures:
        f.add_done_callback(finished.put)
    done, poll_s = 0, min(1.0, timeout_s / 4)
    alone_since = None  # time.monotonic() when the scheduler was first seen without a worker
    try:
        had_worker = bool(client.nthreads())
        while done < len(futures):
            try:
                result = _result(finished.get(timeout=poll_s), poll_s, address, finished)
            except queue.Empty:
                result = _LOST
            if result is not _LOST:
                done += 1
                alone_since = None
                yield result
                continue
            workers = len(client.nthreads())
            had_worker = had_worker or bool(workers)
            now = time.monotonic()
            alone_since = None if workers else alone_since or now
            if alone_since is not None and now - alone_since >= timeout_s:
                what = "the cluster lost its last worker" if had_worker else "the scheduler has no worker"
                raise NoWorkers(f"--scheduler {address}: {what}, and none joined within {timeout_s:g} s (--timeout); "
                                f"{done} of {len(futures)} recordings fitted; start workers (dask worker {address}) or "
                                "check the scheduler address, then run again", done, len(futures))
    except (CancelledError, OSError):  # the client lost the scheduler: its tasks are cancelled
        raise ValueError(f"--scheduler {address}: the Dask scheduler went away after {done} of {len(futures)} "
                         "recordings; restart it (dask scheduler) and its workers, then run again") from None


_LOST = object()  # no result: none finished, or a finished one's worker was lost before it was fetched


def _result(f: Any, timeout_s: float, address: str, finished: queue.SimpleQueue) -> Any:
    """The result of the finished future `f`, or _LOST when its worker went away first (the scheduler computes it
    again, and `f` goes to `finished` again when it finishes)."""
    try:
        return f.result(timeout=timeout_s)
    except TimeoutError:
        f.add_done_callback(finished.put)
        return _LOST
    except (RuntimeError, ImportError, AttributeError) as e:  # the task could not be unpickled or run there
        why = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise ValueError(f"--scheduler {address}: the cluster could not run rig's work ({why}); its scheduler and "
                         "workers need the same rig as this machine (install it there, then restart them)") from None


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
