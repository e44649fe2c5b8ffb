"""Peak memory of this process, for run summaries, the export benchmark and ``lift3d bench``."""

from __future__ import annotations

import sys


def peak_rss_mb() -> float:
    """Peak resident set size of this process (since its last ``exec``) in MiB.

    On Linux this is ``VmHWM`` of ``/proc/self/status``. ``getrusage``'s ``ru_maxrss`` is not used there:
    it survives fork and exec, so a worker started by a parent that once peaked at 1.3 GB reports 1.3 GB.

    Examples
    --------
    >>> peak_rss_mb() > 1.0
    True
    """
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0  # kB
    except OSError:
        pass
    try:
        import resource

        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        return peak / 2**20 if sys.platform == "darwin" else peak / 1024.0  # bytes on macOS, KiB elsewhere
    except ImportError:  # Windows
        import psutil

        return psutil.Process().memory_info().peak_wset / 2**20
