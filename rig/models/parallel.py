"""Several models fitted to the same data at once, in worker processes (a diagnosis's candidate effects).

The workers are forked: they share the parent's data, its grouped nodes (made once before the fork) and
its compiled kernels, and send back only numbers (parameter values, log-likelihood, convergence), from
which the parent makes each `ModelFit` with its own model objects; effects defined in a user's file never
have to be pickled. Fork is POSIX-only, and a forked child must not need a lock another thread holds, so
`fit_models` runs in the calling process when `jobs` is 1, where fork is not available, or when it is not
called from the main thread (the TUI fits in a worker thread while the UI's threads run); the main thread
of the command line may have a progress line's daemon ticker, which the children never touch.
"""

from __future__ import annotations

import multiprocessing
import signal
import threading
from dataclasses import replace
from typing import Callable

from .composition import Model
from .data.model_data import ModelData
from .effects.user_effects import EffectFileError
from .fitting.optimise import fit_data
from .parts.result import ModelFit


def fit_models(models: list[Model], d: ModelData, start: dict[str, float] | None = None, *, jobs: int = 1,
               hold: frozenset[str] = frozenset(), done: Callable[[int], None] | None = None,
               exact_loglik: bool = True) -> list[ModelFit | ValueError]:
    """Each model fitted (without standard errors) from `start`, the parameters in `hold` held there, in order; a
    model that cannot be fitted gives its ValueError (an `EffectFileError` is raised). `done(i)` is called as
    model i finishes. Effects that keep state (an empirical shape's knots) must have it before the call.
    `exact_loglik` False: a model fitted on grouped nodes reports their log-likelihood (`fit_model`)."""
    if jobs > 1 and len(models) > 1:
        for m in models:
            fit_data(m, d)  # grouped nodes made here, once, not in every worker

    def one(i: int) -> object:
        # the fit goes back without its effects (the parent puts its own model back: a user's effects may not pickle)
        r = _fit(models[i], d, start, hold, exact_loglik)
        return r if isinstance(r, Exception) else replace(r, model=Model(models[i].base))

    results = forked_map(one, len(models), jobs=jobs, done=done)
    return [_raised(r if isinstance(r, Exception) else replace(r, model=models[i])) for i, r in enumerate(results)]


#: the function the forked workers of `forked_map` call
_MAP: Callable[[int], object] | None = None


def forked_map(fn: Callable[[int], object], n: int, *, jobs: int = 1, done: Callable[[int], None] | None = None) -> list:
    """[fn(0), ..., fn(n - 1)], computed in up to `jobs` forked worker processes, which inherit whatever `fn` reads
    (results must pickle); in the calling process when `jobs` or `n` is 1, where fork is not available, or off the
    main thread (module docstring). `done(i)` is called as item i finishes."""
    global _MAP
    forkable = "fork" in multiprocessing.get_all_start_methods() and threading.current_thread() is threading.main_thread()
    if jobs <= 1 or n <= 1 or not forkable:
        out = []
        for i in range(n):
            out.append(fn(i))
            if done is not None:
                done(i)
        return out
    _MAP = fn
    try:
        results: list = [None] * n
        pool = multiprocessing.get_context("fork").Pool(min(jobs, n), initializer=_quiet_signals)
        try:
            for i, r in pool.imap_unordered(_map_in_worker, range(n)):
                results[i] = r
                if done is not None:
                    done(i)
            pool.close()
        except BaseException:
            pool.terminate()
            raise
        finally:
            pool.join()
    finally:
        _MAP = None
    return results


def _map_in_worker(i: int) -> tuple[int, object]:
    return i, _MAP(i)  # type: ignore[misc]


def _fit(m: Model, d: ModelData, start: dict[str, float] | None, hold: frozenset[str],
         exact_loglik: bool) -> ModelFit | Exception:

    try:
        return m.fit(d, start=start, errors=False, hold=hold, exact_loglik=exact_loglik)
    except EffectFileError as e:
        return e
    except ValueError as e:
        return e


def _quiet_signals() -> None:
    """In a worker: Ctrl-C is the parent's to handle (it ends the pool), and a terminate ends the worker quietly
    (the command line turns SIGTERM into an interrupt, which a worker must not inherit)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def _raised(r: object) -> ModelFit | ValueError:
    """The fit, or the ValueError that it could not be fitted; an effects-file error is raised."""

    if isinstance(r, EffectFileError):
        raise r
    return r  # type: ignore[return-value]
