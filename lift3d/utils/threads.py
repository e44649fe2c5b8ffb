"""How lift3d's CPU threads behave next to other busy processes (no torch import here: this runs first).

PyTorch's CPU kernels run on OpenMP threads that, by default, *spin* for a while at the end of every parallel
operation, waiting for work. Alone on a machine that saves a few microseconds per operator; next to another
busy process it steals the cores the other threads need, and a training step consists of thousands of
such barriers. Measured on a 2-core machine with one busy 2-thread neighbour (a second ``lift3d train``):
a 2048-ray render went from 80 ms alone to 348 ms with spinning threads, 158 ms with
``OMP_WAIT_POLICY=PASSIVE`` (threads sleep at once) and 226 ms with a single thread. So lift3d asks for
passive waiting — but OpenMP reads the variable once, when torch loads it, so it must be set before the
first ``import torch``: the ``lift3d`` command does it first thing, and ``import lift3d`` does it when
torch is not loaded yet. A value the user set (e.g. ``OMP_WAIT_POLICY=ACTIVE`` on a dedicated machine)
is kept. See docs/troubleshooting.md ("Threads").
"""

from __future__ import annotations

import os
import sys


def prefer_passive_waiting() -> bool:
    """Set ``OMP_WAIT_POLICY=PASSIVE`` unless the user set it or torch is already loaded (then it is too late
    to matter). Returns whether the policy now in force is lift3d's choice."""
    if "OMP_WAIT_POLICY" in os.environ or "torch" in sys.modules:
        return False
    os.environ["OMP_WAIT_POLICY"] = "PASSIVE"
    return True


def threads_from_environment() -> int | None:
    """The thread count the environment asks for: ``LIFT3D_THREADS``, else ``OMP_NUM_THREADS`` (its first
    entry, as OpenMP reads it); None when neither is a positive integer.

    """
    for name in ("LIFT3D_THREADS", "OMP_NUM_THREADS"):
        value = os.environ.get(name, "").split(",")[0].strip()
        if value.isdigit() and int(value) > 0:
            return int(value)
    return None
