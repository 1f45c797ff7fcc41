"""lie_factors.util.memory: the resident and peak sizes a long run reports."""

from __future__ import annotations

import numpy as np

from lie_factors.util import memory


def test_usage_sees_an_allocation_and_the_peak_stays():
    rss0, peak0 = memory.usage()
    a = np.ones(64 << 17)  # 64 MiB, touched
    rss1, peak1 = memory.usage()
    assert rss1 - rss0 > 48 << 20 and peak1 >= rss1 >= rss0
    del a
    rss2, peak2 = memory.usage()
    slack = 1 << 20  # the kernel syncs its per-thread counters lazily
    assert peak2 >= rss1 - slack and rss2 < rss1 - (48 << 20)


def test_sizes_read_as_people_write_them():
    assert memory.size(845 << 20) == "845 MiB"
    assert memory.size(int(1.21 * (1 << 30))) == "1.21 GiB"
    assert memory.size(None) == "?"
    assert memory.describe().startswith("RSS ") and ", peak " in memory.describe()
