"""Keep freed memory for reuse instead of giving it back to the kernel after every frame.

glibc's malloc serves blocks above its mmap threshold (128 KiB at first, raised as such
blocks are freed) with fresh pages, and returns free memory at the top of a heap once there
is more than its trim threshold. A stage receives, decodes and computes on frame-sized
buffers (a 384x288 colour frame is 330 KB, chamfer features 660 KB) on several threads
(zenoh's receive thread, the compute thread), so under the defaults many of these buffers
come back from the kernel zeroed, page by page, every frame: measured on the chamfer
tracker, about 4,200 minor page faults per frame over the stage processes against 680 in
one process, a third of the processes' CPU in the kernel. With a fixed 8 MiB threshold and
keeping up to 32 MiB free per heap, the faults fall to under 100 per frame per process
(``bench/bench_pipeline.py`` prints CPU per frame).

The price is memory held for reuse: at most the trim threshold per malloc arena, and the
arenas are capped at two (the compute thread and zenoh's threads).
"""

from __future__ import annotations

import ctypes
import logging
import sys

__all__ = ["keep_freed_memory"]

log = logging.getLogger("gflow.memory")

M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
M_ARENA_MAX = -8

MMAP_THRESHOLD = 8 * 2**20
TRIM_THRESHOLD = 32 * 2**20
ARENA_MAX = 2

_done = False


def keep_freed_memory() -> bool:
    """Tune glibc malloc for frame-sized buffers (see the module docstring). Idempotent; a
    no-op returning False where there is no glibc (macOS, musl)."""
    global _done
    if _done:
        return True
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    ok = all(mallopt(p, v) == 1 for p, v in ((M_MMAP_THRESHOLD, MMAP_THRESHOLD), (M_TRIM_THRESHOLD, TRIM_THRESHOLD),
                                             (M_ARENA_MAX, ARENA_MAX)))
    if not ok:
        log.debug("mallopt refused a setting; malloc keeps its defaults")
    _done = ok
    return ok
