"""Freed arrays handed back to the operating system as they are freed.

glibc's ``malloc`` serves a block of 128 kB or more with its own ``mmap``, and gives it back on
``free``; but each time such a block is freed it raises that threshold to the block's size (up to
32 MB), so that the next arrays of that size come from the heap, which is given back only from its
top. A diagnosis makes and drops arrays of 1-30 MB by the hundred: without the fix, a process that
has read a 1-hour 1 kHz log holds 0.3 GB of freed heap (``malloc_trim`` returns it), and its peak
is that much higher than what it holds alive. Fixing the threshold (``mallopt(M_MMAP_THRESHOLD)``,
which also stops its raising) keeps every large array in its own mapping, returned when freed.
No C library function of this kind is wrapped by numpy or the standard library, hence ``ctypes``.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import platform

#: glibc's ``M_MMAP_THRESHOLD`` option, and the size from which a block gets its own mapping [bytes]
_M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD = 256 * 1024


def return_freed_arrays() -> bool:
    """Fix glibc's mmap threshold at :data:`MMAP_THRESHOLD` for this process; whether it was set
    (False on another C library, where nothing changes)."""
    if platform.libc_ver()[0] != "glibc":
        return False
    name = ctypes.util.find_library("c")
    if name is None:
        return False
    try:
        mallopt = ctypes.CDLL(name).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD))
