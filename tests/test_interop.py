"""The interop clients (tests/interop.py): a missing one skips on a developer's machine and fails in CI, and
.ci/run installs every Debian package the helper names."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

import interop

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("value, ci", [("", False), ("0", False), ("false", False), ("No", False),
                                       ("true", True), ("1", True), ("yes", True)])
def test_ci_is_read_from_the_environment(monkeypatch, value, ci):
    monkeypatch.setenv("CI", value)
    assert interop.in_ci() is ci
    monkeypatch.delenv("CI")
    assert not interop.in_ci()


def test_missing_client_skips_here_and_fails_in_ci(monkeypatch):
    monkeypatch.setitem(interop.DEBIAN_PACKAGES, "no-such-client-xyz", "no-such-package")
    monkeypatch.delenv("CI", raising=False)
    with pytest.raises(pytest.skip.Exception, match="apt-get install no-such-package"):
        interop.require_tool("no-such-client-xyz")
    with pytest.raises(pytest.skip.Exception, match=r"pip install 'lift3d\[nope\]'"):
        interop.require_module("no_such_module_xyz", pip="pip install 'lift3d[nope]'")
    monkeypatch.setenv("CI", "true")
    with pytest.raises(pytest.fail.Exception, match="no-such-client-xyz is missing in CI .*no-such-package"):
        interop.require_tool("no-such-client-xyz")
    with pytest.raises(pytest.fail.Exception, match=r"no_such_module_xyz is missing in CI .*lift3d\[nope\]"):
        interop.require_module("no_such_module_xyz", pip="pip install 'lift3d[nope]'")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr("sys.platform", "linux")
    with pytest.raises(pytest.fail.Exception, match="a display .*apt-get install xvfb, then run under xvfb-run"):
        interop.require_display()


def test_present_client_is_returned(monkeypatch):
    monkeypatch.setitem(interop.DEBIAN_PACKAGES, "sh", "dash")
    assert Path(interop.require_tool("sh")).name == "sh"
    assert interop.require_module("json", pip="-").dumps([]) == "[]"


def test_ci_installs_every_debian_package_the_tests_name():
    script = (ROOT / ".ci" / "run").read_text()
    clients = dict(item.split(":") for item in re.search(r'^CLIENTS="([^"]*)"', script, re.M).group(1).split())
    for program, package in interop.DEBIAN_PACKAGES.items():
        assert clients.get(program) == package, f".ci/run does not install {package} (for {program})"
    assert "xvfb-run -a make test" in script  # the display of test_show_opens_a_window
