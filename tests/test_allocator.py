"""Freed arrays go back to the system once the diagnosis has fixed glibc's mmap threshold: the
same allocations, in fresh processes, with and without it."""

import platform
import subprocess
import sys

import pytest

_PROGRAM = """
import sys
import numpy as np
from groundstation.core.allocator import return_freed_arrays

def rss_mb():
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmRSS")) / 1024

if sys.argv[1] == "fixed":
    assert return_freed_arrays()
big = np.ones(20_000_000 // 8)  # freed: glibc raises its threshold to this size
del big
arrays, pins = [], []
for _ in range(100):  # 100 MB of 1 MB arrays, each followed by a small object that pins the heap
    arrays.append(np.ones(1_000_000 // 8))
    pins.append(bytearray(4096))
before = rss_mb()
del arrays
print(before - rss_mb())
"""


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="glibc's allocator only")
def test_freed_arrays_return_to_the_system_with_the_threshold_fixed():
    def given_back(mode: str) -> float:
        r = subprocess.run([sys.executable, "-c", _PROGRAM, mode], capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stderr
        return float(r.stdout)

    assert given_back("fixed") > 90.0  # each 1 MB array its own mapping, unmapped when freed
    assert given_back("default") < 10.0  # held in the heap below the pins
