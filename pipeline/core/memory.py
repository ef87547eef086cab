"""Giving freed memory back to the operating system between long stages.

A stage of many medium-sized arrays (a diagnosis round: candidates' columns, fold fits) leaves its freed
memory in the C allocator's heap, where it still counts in the process's resident set and in every process
forked from it (how much: docs/speed.md "Measurements behind the code").
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import sys

_TRIM = []


def _malloc_trim():
    """glibc's ``malloc_trim`` (None elsewhere: macOS, musl)."""
    if not _TRIM:
        fn = None
        if sys.platform.startswith("linux"):
            try:
                fn = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").malloc_trim
                fn.argtypes, fn.restype = [ctypes.c_size_t], ctypes.c_int
            except (OSError, AttributeError):
                fn = None
        _TRIM.append(fn)
    return _TRIM[0]


def release_freed_memory() -> None:
    """Collect unreachable objects, then return the allocator's free pages to the system (glibc); nothing
    else changes: no value a computation reads is touched."""
    gc.collect()
    fn = _malloc_trim()
    if fn is not None:
        fn(0)
