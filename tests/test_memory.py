"""Freed memory given back between a loop's long stages (pipeline.core.memory, issue 32)."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from pipeline.core import memory


def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096 / 2**20


@pytest.mark.skipif(not sys.platform.startswith("linux") or memory._malloc_trim() is None,
                    reason="glibc's malloc_trim is Linux only")
def test_freed_heap_memory_is_given_back():
    """Medium arrays freed under a live one stay in the heap (the resident set keeps them) until
    release_freed_memory() hands them back: what a diagnosis round left behind (350 MB on Series A)."""
    big = np.ones(16 * 2**20 // 8)         # freed: glibc's mmap threshold rises to its size
    del big
    arrays = [np.ones(2**20 // 8) for _ in range(300)]      # 300 x 1 MB, now from the heap
    pin = np.ones(2**20 // 8)                                # above them: the heap cannot shrink from its top
    del arrays
    before = _rss_mb()
    memory.release_freed_memory()
    assert before - _rss_mb() > 150, (before, _rss_mb())
    assert pin.sum() == pin.size                             # what is live is untouched
