"""Reading and checking files, with errors that name the file (one helper for each, used everywhere).

Writing is :mod:`lift3d.utils.atomic`.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

from lift3d.errors import InputError


def read_json(path: str | Path, *, missing: str = "file not found") -> Any:
    """The parsed content of a JSON file.

    Parameters
    ----------
    path : str or Path
        The file.
    missing : str
        The problem reported when the file does not exist (e.g. what to do about it).

    Raises
    ------
    InputError
        Naming the file: ``missing``, ``not valid JSON (line N: ...)`` or ``cannot be read (...)``.

    Examples
    --------
    >>> import tempfile, os
    >>> p = os.path.join(tempfile.mkdtemp(), "a.json")
    >>> _ = open(p, "w").write('{"a": [1, 2]}')
    >>> read_json(p)
    {'a': [1, 2]}
    >>> _ = open(p, "w").write('{"a": [1, 2}')
    >>> read_json(p)
    Traceback (most recent call last):
    ...
    lift3d.errors.InputError: ...a.json: not valid JSON (line 1: Expecting ',' delimiter)
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, missing)
    try:
        with open(path, encoding="utf-8") as fh:
            return json.load(fh)
    except json.JSONDecodeError as exc:
        raise InputError(path, f"not valid JSON (line {exc.lineno}: {exc.msg})") from exc
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, f"cannot be read ({exc})") from exc


def check_writable(path: str | Path, *, folder: bool = False) -> Path:
    """Fail early (before minutes of work) when ``path`` cannot be written.

    Creates the folder (``folder``) or the file's parent folder if needed, and writes and removes a
    temporary file in it.

    Parameters
    ----------
    path : str or Path
        A file to be written, or with ``folder`` a folder to write into.
    folder : bool
        ``path`` is an output folder rather than a file.

    Returns
    -------
    Path

    Raises
    ------
    InputError
        Naming ``path``: it is a folder where a file is wanted, or it is not writable (and why).
    """
    path = Path(path)
    if not folder and path.is_dir():
        raise InputError(path, "is a folder; give a file name")
    target = path if folder else path.parent
    try:
        target.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".lift3d-write-test.", dir=target)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise InputError(path, f"not writable ({exc.strerror or exc})") from exc
    return path
