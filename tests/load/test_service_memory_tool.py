"""benchmarks/service_memory.py reads a process's memory from /proc (the figure it prints; never asserted)."""
from __future__ import annotations

import os

import numpy as np

from benchmarks.service_memory import process_memory_mb


def test_process_memory_grows_with_an_allocation_and_the_peak_is_at_least_the_current():
    rss_before, _ = process_memory_mb(os.getpid())
    block = np.ones(64 * 1024 * 1024 // 8)  # 64 MB, touched
    rss_after, peak = process_memory_mb(os.getpid())
    assert block.sum() > 0
    assert rss_after - rss_before > 50 and peak >= rss_after
