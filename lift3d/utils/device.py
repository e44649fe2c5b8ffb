"""Device and thread selection. Code is device-agnostic: ``--device auto|cpu|cuda[:N]``."""

from __future__ import annotations

import os

import torch

from lift3d.errors import InputError
from lift3d.utils.threads import threads_from_environment


def resolve_device(name: str = "auto") -> torch.device:
    """``auto`` → CUDA when available, else CPU. An unavailable ``cuda`` is a one-line error.

    Examples
    --------
    >>> resolve_device("cpu")
    device(type='cpu')
    """
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        dev = torch.device(name)
    except RuntimeError:
        raise InputError("--device", f"unknown device {name!r} (use auto, cpu or cuda)") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise InputError("--device", "CUDA was requested but torch sees no GPU (use --device cpu or auto)")
    return dev


def available_cpus() -> int:
    """CPUs this process may run on: the affinity mask, capped by a cgroup v2 CPU quota (containers).

    A container limited to 2 CPUs on a 64-core host still sees 64 cores in its affinity mask; starting 64
    threads there makes every step many times slower, so the quota wins.
    """
    try:
        n = len(os.sched_getaffinity(0))
    except AttributeError:  # macOS / Windows
        n = os.cpu_count() or 1
    try:
        quota, period = open("/sys/fs/cgroup/cpu.max").read().split()[:2]
        if quota != "max":
            n = min(n, max(1, -(-int(quota) // int(period))))  # ceil: 1.5 CPUs → 2 threads
    except (OSError, ValueError):
        pass
    return n


def default_threads() -> int:
    """Threads lift3d uses unless told otherwise: ``LIFT3D_THREADS``, else ``OMP_NUM_THREADS``, else every
    CPU this process may use (:func:`available_cpus`)."""
    return threads_from_environment() or available_cpus()


def set_threads(n: int | None = None) -> int:
    """Use ``n`` intra-op threads (default: :func:`default_threads`). Returns the count."""
    n = n or default_threads()
    torch.set_num_threads(n)
    return n
