"""Data-parallel training with torchrun (gloo, 2 CPU processes on this machine)."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lift3d.model.run import load_run
from lift3d.model.run_folder import RunFolder
from lift3d.synth import SynthOptions, make_scene

WORKER = Path(__file__).parent / "helpers" / "dist_worker.py"
OVERRIDES = {
    "field": {"grid": {"resolution_cap": 24, "min_resolution": 12, "head_hidden_dim": 16}},
    "sampling": {"proposal_resolutions": [16], "proposal_samples": [24], "num_samples": 12},
    "data": {"images_per_batch": 4, "rays_per_image": 64, "patch_size": 8},
    "optim": {"steps": 40, "warmup_steps": 5},
    "trainer": {"eval_every": 0, "eval_images": 1, "checkpoint_every": 20, "log_every": 5, "threads": 1},
}


def _run(nproc: int, scene: Path, out: Path, report: Path) -> dict:
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", f"--nproc_per_node={nproc}",
           str(WORKER), str(scene), str(out), str(report), json.dumps(OVERRIDES)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(report.read_text())


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("dist") / "room"
    make_scene(root, SynthOptions(kind="indoor", seed=5, n_views=8, width=32, height=32), progress=False)
    return root


@pytest.mark.slow
def test_two_ranks_match_one_process_and_stay_in_sync(scene, tmp_path):
    one = _run(1, scene, tmp_path / "one", tmp_path / "one.json")
    two = _run(2, scene, tmp_path / "two", tmp_path / "two.json")
    assert two["summary"]["world_size"] == 2
    assert two["summary"]["replicas_identical"] is True
    # Same global batch (4 images = 2 per rank): the loss curves agree within sampling noise.
    # (The total loss is not monotone: the distillation and segment terms switch on during the run, so
    # compare the colour term, which must fall, and the totals, which must agree.)
    log1 = [r for r in RunFolder(Path(one["run"])).read_log() if "total" in r]
    log2 = [r for r in RunFolder(Path(two["run"])).read_log() if "total" in r]
    assert len(log1) == len(log2) == 8
    colour1, colour2 = [r["color"] for r in log1], [r["color"] for r in log2]
    assert np.mean(colour1[-3:]) < 0.9 * colour1[0] and np.mean(colour2[-3:]) < 0.9 * colour2[0]
    assert abs(np.mean(colour1[-3:]) - np.mean(colour2[-3:])) < 0.25 * np.mean(colour1[-3:])
    total1, total2 = [r["total"] for r in log1], [r["total"] for r in log2]
    assert abs(np.mean(total1[-3:]) - np.mean(total2[-3:])) < 0.25 * np.mean(total1[-3:])
    # The checkpoint of the 2-rank run loads in a single process.
    loaded = load_run(two["run"], device="cpu")
    assert loaded.step == 40
    # ...and a 2-rank run resumes in one process.
    from lift3d.train.trainer import train

    res = train(resume=two["run"], overrides={"optim": {"steps": 45}, "trainer": {"threads": 1}}, progress=False,
                print_summary=False)
    assert res.steps == 45
