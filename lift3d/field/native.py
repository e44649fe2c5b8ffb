"""The optional C++ kernels of the grid field (``csrc/native.cpp``), built on first use.

On a CPU the grid field spends most of its time in glue, not arithmetic: computing the 8 corner indices
and trilinear weights of every level, gathering, summing, encoding positions and directions — a dozen
elementwise operators per level, each allocating its temporaries. The kernels here do
each of those in one pass over the points and write straight into the decoder's input matrix; the
backward adds the grid gradients in place, deterministically. The small decoders (a few layers 64 wide) run
fused too, forward and backward (MKL reaches a third of the FMA rate on such narrow products and allocates
every layer's output), and a render marches each ray's density, and decodes and sums its colour and labels,
in one pass per stage (:meth:`lift3d.field.grid.GridField.march` and ``composite_*``).

They are compiled with ``torch.utils.cpp_extension`` the first time a CPU field needs them (20 s of compiler time;
needs a C++ compiler and ninja) into a cache folder, ``$LIFT3D_CACHE_DIR/native`` or
``~/.cache/lift3d/native``, reused afterwards. Without a compiler, or with ``LIFT3D_NATIVE=0``, lift3d uses
the pure-torch path (same results up to float rounding; ``tests/test_native.py`` compares them), after one
warning saying why. GPU tensors always take the torch path.
"""

from __future__ import annotations

import hashlib
import os
import platform
import threading
import warnings
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from lift3d.utils.atomic import write_bytes_atomic

_SOURCE = Path(__file__).resolve().parent / "csrc" / "native.cpp"
_lock = threading.Lock()
_module: Any = None
_failed: str | None = None


def cache_dir() -> Path:
    """Where the compiled kernels are kept (``$LIFT3D_CACHE_DIR/native``, default ``~/.cache/lift3d/native``)."""
    root = os.environ.get("LIFT3D_CACHE_DIR") or os.path.join(os.path.expanduser("~"), ".cache", "lift3d")
    return Path(root) / "native"


def enabled() -> bool:
    """The kernels may be used: not switched off with ``LIFT3D_NATIVE=0``."""
    return os.environ.get("LIFT3D_NATIVE", "1").strip().lower() not in ("0", "false", "no", "off")


def _build_name() -> str:
    """A name unique to the source, torch version and CPU (the build uses ``-march=native``)."""
    h = hashlib.sha1(_SOURCE.read_bytes())
    h.update(torch.__version__.encode())
    h.update(platform.machine().encode())
    try:
        flags = next((ln for ln in Path("/proc/cpuinfo").read_text().splitlines() if ln.startswith("flags")), "")
        h.update(flags.encode())
    except OSError:
        pass
    return f"lift3d_native_{h.hexdigest()[:12]}"


def load() -> Any:
    """The compiled kernels (the namespace ``torch.ops.lift3d``), building them on first use; None when
    unavailable (the reason is warned once)."""
    global _module, _failed
    if _module is not None or _failed is not None or not enabled():
        return _module
    with _lock:
        if _module is not None or _failed is not None:
            return _module
        try:
            from torch.utils import cpp_extension

            build = cache_dir() / _build_name()
            build.mkdir(parents=True, exist_ok=True)
            # Compile a copy kept in the build folder: the build records its sources' paths, so the same source
            # loaded from another checkout (a second clone, a worktree) would otherwise rebuild every time the
            # two alternate (9-12 s each).
            source = build / _SOURCE.name
            if not source.is_file() or source.read_bytes() != _SOURCE.read_bytes():
                write_bytes_atomic(source, _SOURCE.read_bytes())
            cpp_extension.load(
                name=build.name, sources=[str(source)], build_directory=str(build), is_python_module=False,
                extra_cflags=["-O3", "-march=native", "-fopenmp"], extra_ldflags=["-fopenmp"], verbose=False)
            _module = torch.ops.lift3d
        except Exception as exc:  # no compiler, no ninja, a read-only cache ...: the torch path works
            _failed = " ".join(str(exc).split())[:300]
            warnings.warn(f"lift3d: the C++ grid kernels are unavailable ({_failed}); using the slower pure-torch "
                          "path (LIFT3D_NATIVE=0 silences this)", RuntimeWarning, stacklevel=2)
    return _module


def usable(*tensors: Tensor) -> Any:
    """The kernels when every tensor is a float32 CPU tensor and they are available, else None."""
    if not enabled():
        return None
    for t in tensors:
        if t.device.type != "cpu" or t.dtype != torch.float32:
            return None
    return load()
