"""The fork pool, one home: work shared with forked worker processes through a module global.

The workers are forked (Linux), so what they work on is inherited, not pickled: a fitted model, a
campaign of thousands of poses, a design's sparse layouts. Each task's result is the same computation
as in one process, so the numbers are the same whatever the number of workers. :func:`can_fork` says
where forking is possible (Linux, fork available, not from inside a worker).

* :func:`fork_map`: ``[fn(shared, k) for k in range(n)]`` in forked workers;
* :func:`fork_imap`: the same, results as they come (in order), for progress lines;
* :func:`fork_map_async`: the same begun, the caller going on meanwhile;
* :func:`fork_process`: ``fn(shared)`` in one forked process beside this one.
"""

from __future__ import annotations

import multiprocessing as mp
import sys

#: (fn, shared) of the pool being started: read by the forked workers
_SHARED = None


def can_fork() -> bool:
    """Whether worker processes can be forked here: Linux, the fork start method, not a worker itself."""
    return (sys.platform.startswith("linux") and not mp.current_process().daemon
            and "fork" in mp.get_all_start_methods())


def _call(k):
    fn, shared = _SHARED
    return fn(shared, k)


def _run():
    fn, shared = _SHARED
    return fn(shared)


def fork_map(fn, shared, n: int, jobs: int, chunksize: int = 1) -> list:
    """``[fn(shared, k) for k in range(n)]`` in ``jobs`` forked worker processes (in order)."""
    global _SHARED
    _SHARED = (fn, shared)
    try:
        with mp.get_context("fork").Pool(jobs) as pool:
            return pool.map(_call, range(n), chunksize=chunksize)
    finally:
        _SHARED = None


def fork_imap(fn, shared, n: int, jobs: int, chunksize: int = 1):
    """:func:`fork_map`, its results yielded as they come (in order)."""
    global _SHARED
    _SHARED = (fn, shared)
    try:
        with mp.get_context("fork").Pool(jobs) as pool:
            yield from pool.imap(_call, range(n), chunksize=chunksize)
    finally:
        _SHARED = None


def fork_map_async(fn, shared, n: int, jobs: int, chunksize: int = 1):
    """:func:`fork_map` begun: the workers fork here (with ``shared`` as it is now) and work while the caller
    goes on; returns a function that waits for the results (a list, in order) and ends the workers."""
    global _SHARED
    _SHARED = (fn, shared)
    try:
        pool = mp.get_context("fork").Pool(jobs)      # the workers fork here
    finally:
        _SHARED = None
    pending = pool.map_async(_call, range(n), chunksize=chunksize)

    def result() -> list:
        try:
            return pending.get()
        finally:
            pool.terminate()
            pool.join()
    return result


def fork_process(fn, shared, daemon: bool = True):
    """``fn(shared)`` in one forked process, started (``multiprocessing.Process``; the caller joins it)."""
    global _SHARED
    _SHARED = (fn, shared)
    try:
        proc = mp.get_context("fork").Process(target=_run, daemon=daemon)
        proc.start()
    finally:
        _SHARED = None
    return proc


def pipe():
    """A one-way pipe (receive end, send end) for a forked process's result."""
    return mp.get_context("fork").Pipe(duplex=False)
