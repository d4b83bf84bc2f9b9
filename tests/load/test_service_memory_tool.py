"""benchmarks/service_memory.py reads a process's memory from /proc (the figure it prints; never asserted)."""
from __future__ import annotations

import mmap
import os

from benchmarks.service_memory import process_memory_mb


def test_process_memory_grows_with_an_allocation_and_the_peak_is_at_least_the_current():
    # A fresh anonymous mapping, written page by page: unlike a numpy array, it cannot reuse pages that the
    # process freed earlier (and still holds), so the resident set must grow by its size.
    size = 64 * 1024 * 1024
    rss_before, _ = process_memory_mb(os.getpid())
    block = mmap.mmap(-1, size)
    for offset in range(0, size, mmap.PAGESIZE):
        block[offset] = 1
    rss_after, peak = process_memory_mb(os.getpid())
    block.close()
    assert rss_after - rss_before > 50 and peak >= rss_after
