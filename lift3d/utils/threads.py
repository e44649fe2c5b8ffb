"""How lift3d's CPU threads wait between parallel operations (no torch import here: this runs first).

PyTorch's CPU kernels run on OpenMP threads. At the end of every parallel operation the worker threads wait
for the next one, and how they wait decides two things at once:

* **spinning** (busy-waiting; GNU OpenMP's default spins ~300 000 times, a few milliseconds) is fastest
  alone, but next to another busy process the spinning threads take the cores the other threads need, and a
  training step has thousands of these waits. Measured on a 2-core machine with one busy 2-thread
  neighbour: a 2048-ray render went from 80 ms alone to 348 ms.
* **sleeping at once** (``OMP_WAIT_POLICY=PASSIVE``) costs a wake-up at every operation instead. On a
  virtual machine, where an idle virtual CPU is descheduled by the host, that wake-up is slow.
* **a short spin, then sleep** (GNU OpenMP's ``GOMP_SPINCOUNT``): the worker keeps spinning through the
  microseconds between the operations of one render or training step and sleeps in the longer pauses.

Measured on a trained ``fast`` run of tuning room 104 (2026-11-26, 2 threads, medians of 20 steps and 20
renders of 2048 rays, 4 alternating rounds, alone and beside a busy 2-thread neighbour): sleeping at once,
a step took 285 ms alone and 310 ms beside the neighbour (1.1 ×), a render 39 and 64 ms (1.6 ×); with
3 000 spins 233 and 399 ms (1.7 ×), 32 and 68 ms (2.1 ×); 1 000 spins were as slow alone as sleeping at
once (281–326 ms, 44 ms). lift3d uses 3 000 spins: a fifth faster alone, within the 2.5 × it aims for
beside a busy neighbour (though a step there is slower than with sleeping threads).

So with GNU OpenMP (PyTorch's pip wheels on Linux) lift3d sets ``GOMP_SPINCOUNT`` (:data:`SPIN_COUNT`); with
another OpenMP runtime, which does not read it, it keeps ``OMP_WAIT_POLICY=PASSIVE``. OpenMP reads these
variables once, when torch loads it, so they must be set before the first ``import torch``: the ``lift3d``
command does it first thing, and ``import lift3d`` does it when torch is not loaded yet. A value the user
set (``OMP_WAIT_POLICY``, ``GOMP_SPINCOUNT``) is kept. See docs/troubleshooting.md ("Threads").
"""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

#: Busy-wait iterations of GNU OpenMP's worker threads before they sleep (``GOMP_SPINCOUNT``; its default is
#: 300 000). See the module docstring for the measurements behind it.
SPIN_COUNT = 3000


def _torch_bundles_gnu_openmp() -> bool:
    """The installed torch ships GNU OpenMP (``libgomp``), found without importing torch; True when torch
    cannot be located (a system torch links the system's libgomp on Linux)."""
    spec = importlib.util.find_spec("torch")
    if spec is None or not spec.origin:
        return True
    lib = Path(spec.origin).parent / "lib"
    if any(lib.glob("libiomp5*")) or any(lib.glob("libomp.*")):
        return False
    return True


def choose_openmp_waiting() -> str | None:
    """Set how OpenMP threads wait (see the module docstring) unless the user chose already or torch is loaded
    (then it is too late to matter). Returns the setting made, e.g. ``"GOMP_SPINCOUNT=3000"``, or None."""
    if "OMP_WAIT_POLICY" in os.environ or "GOMP_SPINCOUNT" in os.environ or "torch" in sys.modules:
        return None
    if _torch_bundles_gnu_openmp():
        os.environ["GOMP_SPINCOUNT"] = str(SPIN_COUNT)
        return f"GOMP_SPINCOUNT={SPIN_COUNT}"
    os.environ["OMP_WAIT_POLICY"] = "PASSIVE"
    return "OMP_WAIT_POLICY=PASSIVE"


def openmp_waiting() -> str:
    """How OpenMP threads wait in this process, as the environment says (for reports): the wait policy and
    the spin count that are set, or ``"default"``."""
    parts = [f"{name}={os.environ[name]}" for name in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT") if name in os.environ]
    return " ".join(parts) or "default"


def threads_from_environment() -> int | None:
    """The thread count the environment asks for: ``LIFT3D_THREADS``, else ``OMP_NUM_THREADS`` (its first
    entry, as OpenMP reads it); None when neither is a positive integer.

    """
    for name in ("LIFT3D_THREADS", "OMP_NUM_THREADS"):
        value = os.environ.get(name, "").split(",")[0].strip()
        if value.isdigit() and int(value) > 0:
            return int(value)
    return None
