"""Clients of the interop tests: the real tools and libraries that read what lift3d writes.

An interop test reads our file back with the program that consumes it (PCL's ``pcl_pcd2ply``, CloudCompare,
headless Chromium, rosbags, pyoctomap, Open3D, PyVista, a real display for ``--show``) and asks for it here,
inside the test, before using it::

    from interop import require_display, require_module, require_tool

    tool = require_tool("pcl_pcd2ply")

A missing client skips the test on a developer's machine, with a message naming what to install. Under CI
(``CI`` set to anything but ``""``, ``0``, ``false`` or ``no``, as ``.ci/run`` runs) it fails with the same
message: ``.ci/run`` installs every Debian package named in :data:`DEBIAN_PACKAGES` (and ``make test`` the
Python extras), so a skip there would only hide a broken install. ``tests/test_interop.py`` checks that the
two lists agree. DEVELOPERS.md ("CI and the interop tests") says how to run these tests locally.
"""

from __future__ import annotations

import importlib
import os
import shutil
from types import ModuleType
from typing import NoReturn

import pytest

#: Debian package of each client program the interop tests use (``.ci/run`` installs them when missing).
DEBIAN_PACKAGES = {
    "pcl_pcd2ply": "pcl-tools",
    "CloudCompare": "cloudcompare",
    "chromium": "chromium",
    "xvfb-run": "xvfb",  # the display of test_plot.py's --show test (``.ci/run`` runs the suite under it)
}
#: Other names the same program has elsewhere (Ubuntu's chromium-browser, a lower-case CloudCompare).
OTHER_NAMES = {"CloudCompare": ("cloudcompare",), "chromium": ("chromium-browser",)}


def in_ci() -> bool:
    """Whether the suite runs in CI, where a missing client is a failure instead of a skip."""
    return os.environ.get("CI", "").strip().lower() not in ("", "0", "false", "no")


def missing(what: str, install: str) -> NoReturn:
    """Skip (developer's machine) or fail (CI) the calling test: ``what`` is missing, ``install`` fixes it."""
    __tracebackhide__ = True  # report the skip at the test's line, not here
    if in_ci():
        pytest.fail(f"{what} is missing in CI ({install}; .ci/run installs it)", pytrace=False)
    pytest.skip(f"{what} is missing ({install})")


def require_tool(program: str) -> str:
    """The path of ``program`` (a key of :data:`DEBIAN_PACKAGES`, or one of its other names) on PATH; else
    skip/fail naming its Debian package."""
    __tracebackhide__ = True
    for name in (program, *OTHER_NAMES.get(program, ())):
        path = shutil.which(name)
        if path:
            return path
    missing(program, f"Debian: apt-get install {DEBIAN_PACKAGES[program]}")


def require_module(name: str, pip: str) -> ModuleType:
    """Import ``name``; when it is not installed skip/fail naming the pip command that installs it."""
    __tracebackhide__ = True
    try:
        return importlib.import_module(name)
    except ImportError:
        missing(f"Python module {name}", pip)


def require_display() -> None:
    """A display an interactive VTK window can open on (``DISPLAY``, e.g. from ``xvfb-run``); else skip/fail."""
    __tracebackhide__ = True
    from lift3d.viz.points import has_display

    if not has_display():
        missing("a display (DISPLAY unset, or VTK cannot open a window)",
                f"Debian: apt-get install {DEBIAN_PACKAGES['xvfb-run']}, then run under xvfb-run -a")
