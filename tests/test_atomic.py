"""Atomic writes: readers see the old complete file or the new complete file, never a half-written one."""

from __future__ import annotations

import errno
import json
import os
import stat
import tempfile
from pathlib import Path

import numpy as np
import pytest

from lift3d.errors import InputError
from lift3d.utils.atomic import atomic_open, write_bytes_atomic, write_json_atomic


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def test_success_replaces_the_file_and_leaves_no_temp(tmp_path: Path) -> None:
    path = tmp_path / "out.txt"
    path.write_text("old")
    with atomic_open(path, "w") as f:
        f.write("new")
        assert path.read_text() == "old"  # nothing visible before the rename
    assert path.read_text() == "new"
    assert os.listdir(tmp_path) == ["out.txt"]


def test_exception_keeps_the_old_file_and_removes_the_temp(tmp_path: Path) -> None:
    path = tmp_path / "checkpoint.pt"
    path.write_bytes(b"old complete file")
    with pytest.raises(RuntimeError, match="killed mid-write"):
        with atomic_open(path) as f:
            f.write(b"half of the new")
            raise RuntimeError("killed mid-write")
    assert path.read_bytes() == b"old complete file"
    assert os.listdir(tmp_path) == ["checkpoint.pt"]


def test_exception_before_first_write_creates_nothing(tmp_path: Path) -> None:
    with pytest.raises(KeyboardInterrupt):
        with atomic_open(tmp_path / "new.json", "w"):
            raise KeyboardInterrupt
    assert os.listdir(tmp_path) == []


def test_os_error_while_writing_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "points.ply"
    with pytest.raises(InputError, match="could not be written") as info:
        with atomic_open(path) as f:
            f.write(b"x")
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    assert info.value.where == str(path) and "No space left" in str(info.value)
    assert os.listdir(tmp_path) == []


def test_new_files_get_normal_permissions(tmp_path: Path) -> None:
    # mkstemp makes 0600 files; the renamed result must look like any file open() would create.
    path = tmp_path / "classes.json"
    write_json_atomic(path, {"a": 1})
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~_umask()


def test_replacing_keeps_the_existing_permissions(tmp_path: Path) -> None:
    path = tmp_path / "run.sh"
    path.write_text("old")
    path.chmod(0o750)
    write_bytes_atomic(path, b"new")
    assert stat.S_IMODE(path.stat().st_mode) == 0o750 and path.read_bytes() == b"new"


def test_creates_missing_parent_folders(tmp_path: Path) -> None:
    path = tmp_path / "a" / "b" / "c.bin"
    write_bytes_atomic(path, b"\x00\x01")
    assert path.read_bytes() == b"\x00\x01"


def test_json_converts_numpy(tmp_path: Path) -> None:
    path = tmp_path / "m.json"
    write_json_atomic(path, {"n": np.int64(3), "x": np.float32(0.5), "a": np.arange(3), "p": Path("x/y")})
    assert json.loads(path.read_text()) == {"n": 3, "x": 0.5, "a": [0, 1, 2], "p": "x/y"}


def test_only_write_modes() -> None:
    with pytest.raises(ValueError, match="only writes"):
        with atomic_open("x.txt", "r"):
            pass


def _chmod_is_enforced(directory: Path) -> bool:
    """False when running as root (or on a filesystem ignoring modes): then a 0o500 folder stays writable."""
    probe = directory / "probe"
    try:
        probe.touch()
    except PermissionError:
        return True
    probe.unlink()
    return False


def test_read_only_directory_names_the_directory(tmp_path: Path) -> None:
    folder = tmp_path / "readonly"
    folder.mkdir()
    folder.chmod(0o500)
    try:
        if not _chmod_is_enforced(folder):
            pytest.skip("permissions are not enforced (running as root?)")
        with pytest.raises(InputError, match="cannot write here") as info:
            write_bytes_atomic(folder / "out.bin", b"data")
        assert info.value.where == str(folder)
        assert os.listdir(folder) == []
    finally:
        folder.chmod(0o700)


def test_unwritable_directory_error_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The same error path without relying on file permissions (root ignores them)."""
    def refuse(*args, **kwargs):
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES))

    monkeypatch.setattr(tempfile, "mkstemp", refuse)
    with pytest.raises(InputError) as info:
        write_bytes_atomic(tmp_path / "sub" / "out.bin", b"data")
    assert info.value.where == str(tmp_path / "sub")
    assert "cannot write here" in str(info.value) and "Permission denied" in str(info.value)
