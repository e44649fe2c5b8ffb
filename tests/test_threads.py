"""lift3d chooses its OpenMP wait policy before torch loads and its thread count from the environment."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from lift3d.utils.device import available_cpus, default_threads, set_threads
from lift3d.utils.threads import prefer_passive_waiting

ROOT = Path(__file__).resolve().parent.parent


def _python(code: str, **env: str) -> str:
    base = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "LIFT3D_THREADS", "OMP_NUM_THREADS")}
    base.update(env, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-c", code], env=base, capture_output=True, text=True,
                          check=True).stdout.strip()


def test_import_lift3d_asks_for_passive_waiting_before_torch_loads():
    code = "import os, sys, lift3d; print(os.environ.get('OMP_WAIT_POLICY'), 'torch' in sys.modules)"
    assert _python(code) == "PASSIVE False"
    assert _python(code, OMP_WAIT_POLICY="ACTIVE") == "ACTIVE False"  # the user's choice stays


def test_the_cli_sets_the_policy_before_building_any_parser():
    code = ("import os, sys\nfrom lift3d.cli.main import main\n"
            "try:\n    main(['train', '--help'])\nexcept SystemExit:\n    pass\n"
            "print(os.environ.get('OMP_WAIT_POLICY'), file=sys.stderr)")
    base = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    out = subprocess.run([sys.executable, "-c", code], env=dict(base, PYTHONPATH=str(ROOT)), capture_output=True,
                         text=True, check=True)
    # `train --help` builds the torch-backed parser: the policy must be in place before that.
    assert out.stderr.strip().splitlines()[-1] == "PASSIVE"


def test_too_late_once_torch_is_loaded(monkeypatch):
    monkeypatch.delenv("OMP_WAIT_POLICY", raising=False)
    assert "torch" in sys.modules
    assert prefer_passive_waiting() is False and "OMP_WAIT_POLICY" not in os.environ


@pytest.mark.parametrize("env, expected", [
    ({}, None),
    ({"OMP_NUM_THREADS": "1"}, 1),
    ({"LIFT3D_THREADS": "1", "OMP_NUM_THREADS": "3"}, 1),  # lift3d's own variable first
    ({"OMP_NUM_THREADS": "junk"}, None),
])
def test_thread_count_follows_lift3d_threads_then_omp_num_threads(monkeypatch, env, expected):
    for name in ("LIFT3D_THREADS", "OMP_NUM_THREADS"):
        monkeypatch.delenv(name, raising=False)
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    assert default_threads() == (expected or available_cpus())
    before = torch.get_num_threads()
    try:
        assert set_threads() == torch.get_num_threads() == (expected or available_cpus())
        assert set_threads(1) == 1  # an explicit count (a --threads flag) wins
    finally:
        torch.set_num_threads(before)
