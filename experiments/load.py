"""A loaded controller computer for the experiments: one busy loop pinned to each core (`taskset`)
beside the nodes, for as long as a block runs."""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
from collections.abc import Iterator

BUSY = "while True: pass"


@contextlib.contextmanager
def busy_cores(loaded: bool) -> Iterator[None]:
    """One busy loop pinned to each core while the block runs (none when not ``loaded``)."""
    loops = []
    if loaded:
        for core in range(os.cpu_count() or 1):
            loops.append(subprocess.Popen(["taskset", "-c", str(core), sys.executable, "-c", BUSY]))
    try:
        yield
    finally:
        for p in loops:
            p.kill()
            p.wait()
