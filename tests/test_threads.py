"""lift3d chooses how OpenMP threads wait before torch loads, and its thread count from the environment."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from lift3d.utils.device import available_cpus, default_threads, set_threads
from lift3d.utils import threads
from lift3d.utils.threads import SPIN_COUNT, choose_openmp_waiting

ROOT = Path(__file__).resolve().parent.parent


def _python(code: str, **env: str) -> str:
    base = {k: v for k, v in os.environ.items()
            if k not in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT", "LIFT3D_THREADS", "OMP_NUM_THREADS")}
    base.update(env, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-c", code], env=base, capture_output=True, text=True,
                          check=True).stdout.strip()


WAITING = "import os, sys, lift3d; print(os.environ.get('OMP_WAIT_POLICY'), os.environ.get('GOMP_SPINCOUNT'), " \
          "'torch' in sys.modules)"


def test_import_lift3d_asks_for_a_short_spin_before_torch_loads():
    # This torch bundles GNU OpenMP (pip's Linux wheels do), which reads GOMP_SPINCOUNT.
    assert threads._torch_bundles_gnu_openmp()
    assert _python(WAITING) == f"None {SPIN_COUNT} False"
    # The user's choice stays, either variable.
    assert _python(WAITING, OMP_WAIT_POLICY="ACTIVE") == "ACTIVE None False"
    assert _python(WAITING, GOMP_SPINCOUNT="0") == "None 0 False"


def test_another_openmp_runtime_gets_passive_waiting(monkeypatch):
    for name in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setattr(threads, "_torch_bundles_gnu_openmp", lambda: False)
    monkeypatch.delitem(sys.modules, "torch")  # (as before torch loads; restored afterwards)
    assert choose_openmp_waiting() == "OMP_WAIT_POLICY=PASSIVE"
    assert os.environ["OMP_WAIT_POLICY"] == "PASSIVE" and "GOMP_SPINCOUNT" not in os.environ


def test_the_cli_sets_the_policy_before_building_any_parser():
    code = ("import os, sys\nfrom lift3d.cli.main import main\n"
            "try:\n    main(['train', '--help'])\nexcept SystemExit:\n    pass\n"
            "print(os.environ.get('GOMP_SPINCOUNT'), file=sys.stderr)")
    base = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")}
    out = subprocess.run([sys.executable, "-c", code], env=dict(base, PYTHONPATH=str(ROOT)), capture_output=True,
                         text=True, check=True)
    # `train --help` builds the torch-backed parser: the policy must be in place before that.
    assert out.stderr.strip().splitlines()[-1] == str(SPIN_COUNT)


def test_too_late_once_torch_is_loaded(monkeypatch):
    for name in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT"):
        monkeypatch.delenv(name, raising=False)
    assert "torch" in sys.modules
    assert choose_openmp_waiting() is None
    assert "OMP_WAIT_POLICY" not in os.environ and "GOMP_SPINCOUNT" not in os.environ


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
