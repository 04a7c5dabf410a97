"""`stereodic.bench.run_isolated`: the peak memory it reports is the child's own."""

import numpy as np

from stereodic.bench import peak_rss_bytes, run_isolated

MB = 2 ** 20


def _allocate(mb: int) -> float:
    """Touch `mb` MiB of memory and return a number computed from it."""
    return float(np.ones(mb * MB // 8).sum())


def test_child_peak_counts_its_own_memory_not_the_parents():
    _, small, _ = run_isolated(_allocate, 1)
    held = np.ones(600 * MB // 8)              # the parent grows by 600 MiB before the next child
    assert peak_rss_bytes() > 600 * MB
    _, after, _ = run_isolated(_allocate, 1)
    _, large, result = run_isolated(_allocate, 300)
    assert result == 300 * MB // 8
    assert abs(after - small) < 100 * MB
    assert 250 * MB < large - small < 350 * MB
    del held
