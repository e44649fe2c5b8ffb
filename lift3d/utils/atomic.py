"""Atomic file writes: temp file in the same folder, fsync, rename.

A killed process or a full disk never leaves a half-written checkpoint or export behind: readers see
either the previous complete file or the new complete file.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import stat
import tempfile
from pathlib import Path
from typing import IO, Any, Iterator

from lift3d.errors import InputError


@contextlib.contextmanager
def atomic_open(path: str | Path, mode: str = "wb") -> Iterator[IO[Any]]:
    """Open a temporary file beside ``path``; on success fsync it and rename it onto ``path``.

    On any exception the temporary file is removed and ``path`` is untouched. The new file keeps the
    permissions of the file it replaces (a new file gets ``0o666`` minus the umask, as with ``open``).

    Examples
    --------
    >>> with atomic_open("/tmp/lift3d_doctest.txt", "w") as f:
    ...     _ = f.write("hello")
    """
    path = Path(path)
    if "w" not in mode:
        raise ValueError("atomic_open only writes")
    directory = path.parent
    try:
        directory.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=directory)
    except OSError as exc:
        raise InputError(directory, f"cannot write here ({exc.strerror or exc})") from exc
    try:
        with os.fdopen(fd, mode) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, _final_mode(path))
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(exc, OSError) and not isinstance(exc, InputError):
            raise InputError(path, f"could not be written ({exc.strerror or exc})") from exc
        raise
    _fsync_dir(directory)


def _final_mode(path: Path) -> int:
    """Permissions for the renamed file: those of the file being replaced, else what ``open()`` would give
    a new file (0o666 minus the umask). ``mkstemp`` creates 0o600 files, which would otherwise leave every
    export and scene file unreadable to other users (a robot's mapping process, a shared data folder)."""
    try:
        return stat.S_IMODE(os.stat(path).st_mode)
    except OSError:
        return 0o666 & ~_UMASK


def _current_umask() -> int:
    # The umask can only be read by setting it; do it once at import, before worker threads exist.
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


_UMASK = _current_umask()


def _fsync_dir(directory: Path) -> None:
    # The rename itself must reach the disk for the new file to survive a power cut.
    with contextlib.suppress(OSError):
        fd = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def write_bytes_atomic(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_open(path, "wb") as f:
        f.write(data)


def write_text_atomic(path: str | Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    write_bytes_atomic(path, text.encode("utf-8"))


def write_json_atomic(path: str | Path, obj: Any, indent: int | None = 2) -> None:
    """Serialise ``obj`` as JSON and write it atomically (numpy scalars and arrays are converted)."""
    write_text_atomic(path, json.dumps(obj, indent=indent, default=_json_default) + "\n")


def _json_default(o: Any) -> Any:
    import numpy as np

    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def save_torch_atomic(path: str | Path, obj: Any) -> None:
    """``torch.save`` into memory, then write atomically (checkpoints)."""
    import torch

    buf = io.BytesIO()
    torch.save(obj, buf)
    write_bytes_atomic(path, buf.getvalue())


@contextlib.contextmanager
def atomic_dir(path: str | Path) -> Iterator[Path]:
    """Build a folder under a temporary name beside ``path``; on success swap it in place of ``path``.

    Yields the path to fill, not yet created (some writers, rosbag2's among them, refuse an existing
    folder), which already has ``path``'s own name (tools that name files after their folder, as rosbag2
    does, see the final name) inside a hidden temporary parent. On any exception the
    temporary tree is removed and ``path`` is untouched; on success every file is fsynced and an earlier
    ``path`` is replaced (two renames: a reader sees the old folder, briefly none, then the new one).

    Examples
    --------
    >>> import tempfile
    >>> d = Path(tempfile.mkdtemp())
    >>> with atomic_dir(d / "bag") as tmp:
    ...     tmp.mkdir()
    ...     _ = (tmp / "bag.txt").write_text("x")
    >>> sorted(p.name for p in d.iterdir()), (d / "bag" / "bag.txt").read_text()
    (['bag'], 'x')
    """
    import shutil

    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        parent = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    except OSError as exc:
        raise InputError(path.parent, f"cannot write here ({exc.strerror or exc})") from exc
    staged = parent / path.name
    old = parent / (path.name + ".old")
    try:
        yield staged
        for f in staged.rglob("*"):
            if f.is_file():
                with open(f, "rb+") as fh:
                    os.fsync(fh.fileno())
        if path.exists():
            os.replace(path, old)
        os.replace(staged, path)
        _fsync_dir(path.parent)
    except BaseException as exc:
        if old.exists() and not path.exists():
            os.replace(old, path)  # put the earlier folder back
        shutil.rmtree(parent, ignore_errors=True)
        if isinstance(exc, OSError) and not isinstance(exc, InputError):
            raise InputError(path, f"could not be written ({exc.strerror or exc})") from exc
        raise
    shutil.rmtree(parent, ignore_errors=True)
