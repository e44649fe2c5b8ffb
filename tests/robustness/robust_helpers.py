"""Helpers of the robustness suite (docs/robustness.md); fixtures are in conftest.py.

* :func:`run_cli` / :func:`run_cli_many`: the real ``lift3d`` entry point in subprocesses (2 at a time: the
  CI machine has 2 cores, and every process spends ~3 s importing torch);
* :func:`cli`: the same entry point in-process (``lift3d.cli.main.main``), output captured at the file
  descriptor level (so what C libraries print on fd 2 counts too);
* :func:`assert_one_line_error`: the bad-input contract (exit code 2, exactly one stderr line
  ``lift3d <verb>: error: ...`` naming the file, no traceback);
* :func:`edit_json`, :func:`scaled_scene`, :func:`copy_run`: damaged / transformed copies of the fixtures;
* :func:`full_disk` (simulated ENOSPC in the atomic writer) and :func:`tmpfs` (a real tiny or read-only
  filesystem when the test may mount one, else a skip).
"""

from __future__ import annotations

import contextlib
import copy
import errno
import json
import os
import shutil
import subprocess
import sys
import types
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, Callable, Iterator

import pytest

#: Tiny training settings (cf. tests/test_train.py::TINY, smaller still: no patches, no perceptual prior).
TINY = {
    "field": {"grid": {"resolution_cap": 24, "min_resolution": 16, "levels": 2, "head_hidden_dim": 32}},
    "sampling": {"proposal_resolutions": [16], "proposal_samples": [24], "num_samples": 12},
    "data": {"images_per_batch": 2, "rays_per_image": 64, "patch_size": 0},
    "losses": {"feature": 0.0},
    "optim": {"steps": 40, "warmup_steps": 5},
    "trainer": {"eval_every": 0, "eval_images": 2, "checkpoint_every": 20, "log_every": 10, "seed": 0},
}


def tiny(**changes) -> dict:
    """A deep copy of :data:`TINY` with ``section={key: value}`` updates."""
    out = copy.deepcopy(TINY)
    for section, values in changes.items():
        out.setdefault(section, {}).update(values)
    return out


def tiny_flags(**changes) -> list[str]:
    """:func:`tiny` as ``lift3d train`` flags (``--optim.steps 40 --field.grid.levels 2 ...``)."""
    flags: list[str] = []

    def add(path: str, values: dict) -> None:
        nonlocal flags
        for key, value in values.items():
            if isinstance(value, dict):  # a nested section, e.g. field.grid
                add(f"{path}.{key}", value)
                continue
            flag = f"--{path}.{key.replace('_', '-')}"
            flags += [flag, *map(str, value)] if isinstance(value, list) else [flag, str(value)]

    for section, values in tiny(**changes).items():
        add(section, values)
    return flags


def cli_env() -> dict[str, str]:
    env = dict(os.environ)
    env.update(OMP_NUM_THREADS="1", LIFT3D_THREADS="1", MKL_NUM_THREADS="1", PYTHONUNBUFFERED="1")
    env.pop("LIFT3D_DEBUG", None)
    return env


def run_cli(args: list[str], timeout: float = 600, cwd: Path | None = None) -> subprocess.CompletedProcess:
    """``python -m lift3d ARGS`` in a subprocess (text output captured)."""
    return subprocess.run([sys.executable, "-m", "lift3d", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, env=cli_env(), cwd=cwd)


def run_cli_many(arg_lists: list[list[str]], timeout: float = 600) -> list[subprocess.CompletedProcess]:
    """Several CLI calls, two at a time, results in order."""
    with ThreadPoolExecutor(max_workers=2) as pool:
        return list(pool.map(lambda a: run_cli(a, timeout=timeout), arg_lists))


def cli(capfd, *args) -> subprocess.CompletedProcess:
    """``lift3d ARGS`` in this process; returns exit code and the captured stdout/stderr like a subprocess.

    An exception escaping ``main`` (the raw traceback a user would see) propagates and fails the test."""
    from lift3d.cli.main import main

    capfd.readouterr()
    rc = main([str(a) for a in args])
    out, err = capfd.readouterr()
    return subprocess.CompletedProcess(list(map(str, args)), rc, out, err)


def assert_one_line_error(proc: subprocess.CompletedProcess, verb: str, *fragments: str) -> str:
    """Exit code 2, stderr is ONE line ``lift3d <verb>: error: ...`` holding every fragment, no traceback.
    Returns that line."""
    err = proc.stderr
    context = f"\n--- exit code {proc.returncode}\n--- stderr:\n{err}\n--- stdout:\n{proc.stdout[-2000:]}"
    assert proc.returncode == 2, context
    assert "Traceback" not in err and "Traceback" not in proc.stdout, context
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, context
    line = lines[0]
    assert line.startswith(f"lift3d {verb}: error: "), context
    for frag in fragments:
        assert str(frag) in line, f"{frag!r} not in the message{context}"
    return line


def no_temp_files(*folders: Path) -> list[Path]:
    """Leftover temporary files (``atomic_open``'s ``.<name>.XXXX.tmp``) below the folders."""
    out = []
    for folder in folders:
        out += [p for p in Path(folder).rglob("*") if p.name.endswith(".tmp") or ".lift3d-write-test" in p.name]
    return out


def copy_scene(src: Path, dst: Path) -> Path:
    """A private copy of a scene folder (the session fixtures must stay untouched)."""
    shutil.copytree(src, dst)
    return dst


def copy_run(src: Path, dst: Path) -> Path:
    """A private copy of a run folder (its config still points at the session scene)."""
    shutil.copytree(src, dst)
    return dst


def edit_json(path: Path, change: Callable[[Any], Any]) -> None:
    """Load ``path``, let ``change`` mutate the document in place (its return value is ignored), write it
    back (NaN / inf as Python writes them: ``NaN``, ``Infinity``)."""
    doc = json.loads(Path(path).read_text())
    change(doc)
    Path(path).write_text(json.dumps(doc))


def scaled_scene(src: Path, dst: Path, s: float) -> Path:
    """A copy of a scene with every length multiplied by ``s``: camera positions (written and true), the scene box, depth
    (through ``depth_unit_scale_factor``; the PNGs are untouched) and ``gt/points.ply``."""
    import numpy as np

    from lift3d.data.ply import read_labelled_ply, write_labelled_ply

    copy_scene(src, dst)

    def scale(meta):
        for fr in meta["frames"]:
            for key in ("transform_matrix", "gt_transform_matrix"):  # the written and the true pose
                for row in fr.get(key, [])[:3]:
                    row[3] *= s
        if "scene_box" in meta:
            meta["scene_box"]["aabb"] = (np.asarray(meta["scene_box"]["aabb"]) * s).tolist()
        meta["depth_unit_scale_factor"] = meta.get("depth_unit_scale_factor", 1e-3) * s

    edit_json(dst / "transforms.json", scale)
    ply = dst / "gt" / "points.ply"
    if ply.is_file():
        pts = read_labelled_ply(ply)
        write_labelled_ply(ply, pts["xyz"] * s, rgb=pts.get("rgb"), semantic=pts["semantic"], instance=pts["instance"])
    return dst


class _FullDisk:
    """State of :func:`full_disk`: which atomic writes failed."""

    def __init__(self, free_bytes: int, match: str):
        self.free = free_bytes
        self.match = match
        self.failed: list[str] = []


@contextlib.contextmanager
def full_disk(free_bytes: int = 0, match: str = "") -> Iterator[_FullDisk]:
    """Simulate a disk that fills up under ``lift3d.utils.atomic``: files whose temp name contains
    ``match`` may use ``free_bytes`` in total; the write that crosses the limit writes what fits, then raises
    ``OSError(ENOSPC)`` — exactly what a full disk does to a ``write`` — and a half-written temp file is left
    for the atomic writer to clean up. Other writes (and other modules) are untouched; the disk is "freed"
    when the block ends."""
    import lift3d.utils.atomic as atomic

    if not os.path.isdir("/proc/self/fd"):
        pytest.skip("the simulated disk names files via /proc/self/fd (Linux)")
    state = _FullDisk(free_bytes, match)
    real_fdopen = os.fdopen

    class _Filling:
        def __init__(self, f, name):
            self._f, self._name = f, name

        def write(self, data):
            if len(data) > state.free:
                self._f.write(data[: state.free])
                self._f.flush()
                state.free = 0
                state.failed.append(self._name)
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            state.free -= len(data)
            return self._f.write(data)

        def __getattr__(self, name):
            return getattr(self._f, name)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return self._f.__exit__(*exc)

    def fdopen(fd, *args, **kwargs):
        f = real_fdopen(fd, *args, **kwargs)
        try:
            name = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            name = ""
        return _Filling(f, name) if state.match in os.path.basename(name) else f

    fake_os = types.SimpleNamespace(**{k: getattr(os, k) for k in dir(os) if not k.startswith("__")})
    fake_os.fdopen = fdopen
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(atomic, "os", fake_os)
        yield state


@contextlib.contextmanager
def tmpfs(path: Path, size: str = "1m", read_only: bool = False) -> Iterator[Path]:
    """Mount a real tmpfs of ``size`` (optionally read-only) at ``path`` for the block; skip the test when
    this process may not mount (not root, no CAP_SYS_ADMIN, no ``mount``: the usual CI runner)."""
    path.mkdir(parents=True, exist_ok=True)
    opts = f"size={size}" + (",ro" if read_only else "")
    mount = shutil.which("mount")
    if mount is None or not hasattr(os, "geteuid") or os.geteuid() != 0:
        pytest.skip("needs root to mount a tmpfs")
    proc = subprocess.run([mount, "-t", "tmpfs", "-o", opts, "tmpfs", str(path)], capture_output=True, text=True)
    if proc.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {proc.stderr.strip()}")
    try:
        yield path
    finally:
        subprocess.run([shutil.which("umount") or "umount", "-l", str(path)], capture_output=True)


def writes_blocked_by_permissions(folder: Path) -> bool:
    """True when a chmod 0o555 folder really refuses new files (false for root, which ignores modes)."""
    folder.mkdir(parents=True, exist_ok=True)
    folder.chmod(0o555)
    try:
        probe = folder / ".probe"
        probe.write_bytes(b"")
        probe.unlink()
        return False
    except PermissionError:
        return True
    finally:
        folder.chmod(0o755)
