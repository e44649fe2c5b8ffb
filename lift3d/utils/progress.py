"""Progress bars (tqdm) with one switch: ``LIFT3D_NO_PROGRESS=1`` or ``disable=True`` silences them."""

from __future__ import annotations

import os
from typing import Iterable, TypeVar

from tqdm.auto import tqdm

T = TypeVar("T")


def progress_bar(iterable: Iterable[T] | None = None, *, desc: str = "", total: int | None = None,
                 disable: bool = False, leave: bool = True, unit: str = "it") -> "tqdm[T]":
    """A tqdm progress bar on stderr, refreshed at most twice a second."""
    disable = disable or os.environ.get("LIFT3D_NO_PROGRESS", "") not in ("", "0")
    return tqdm(iterable, desc=desc, total=total, disable=disable, leave=leave, unit=unit,
                mininterval=0.5, dynamic_ncols=True)
