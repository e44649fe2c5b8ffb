"""Every random draw and tensor follows the training device.

On a CPU-only machine a CPU generator and CPU tensors always agree, so the first test makes a mismatch
visible anyway: every ``torch.rand*`` call that takes a generator must name its ``device`` explicitly and
that device must be the generator's (a draw that relies on the CPU default and is then moved with ``.to``
is exactly what breaks with a CUDA generator). The CUDA smoke test runs the same path on a GPU when there
is one.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
import torch

from lift3d.export import export_run
from lift3d.model.run import load_run
from lift3d.train.trainer import Trainer, train

# A few steps through every code path that draws random numbers: batches with patches, jittered samples,
# random backgrounds, L_tv, proposal resampling and occupancy-grid updates.
SHORT = {
    "field": {"grid": {"resolution_cap": 16, "min_resolution": 8, "head_hidden_dim": 16},
              "occupancy": {"resolution": 8, "start": 2, "update_every": 2}},
    "sampling": {"proposal_resolutions": [12], "proposal_samples": [16], "num_samples": 8},
    "data": {"images_per_batch": 2, "rays_per_image": 32, "patch_size": 4},
    "optim": {"steps": 6, "warmup_steps": 2},
    "trainer": {"eval_every": 0, "eval_images": 1, "checkpoint_every": 1000, "log_every": 2},
}

_DRAWS = ("rand", "randn", "randint", "randperm", "normal")


@pytest.fixture
def checked_draws(monkeypatch):
    """Wrap torch's random draws: a draw with a generator must name a device, the generator's own."""
    seen = []

    def wrap(name, fn):
        @functools.wraps(fn)
        def checked(*args, **kwargs):
            gen = kwargs.get("generator")
            if gen is not None:
                dev = kwargs.get("device")
                assert dev is not None, f"torch.{name} with a generator but no device (defaults to the CPU)"
                assert torch.device(dev).type == gen.device.type, \
                    f"torch.{name}: device {dev} but a generator on {gen.device}"
                seen.append((name, gen.device.type))
            return fn(*args, **kwargs)
        return checked

    for name in _DRAWS:
        monkeypatch.setattr(torch, name, wrap(name, getattr(torch, name)))
    return seen


def _train_render_export(scene, out, device: str) -> None:
    overrides = {**SHORT, "trainer": {**SHORT["trainer"], "device": device}}
    result = train(scene, preset="fast", output_dir=out, overrides=overrides, progress=False, print_summary=False)
    run = load_run(result.run.path, device=device)
    assert run.device.type == torch.device(device).type
    assert all(p.device.type == run.device.type for p in run.model.parameters())
    assert all(b.device.type == run.device.type for b in run.model.buffers())
    o = np.zeros((5, 3), np.float32)
    d = np.tile(np.array([[1.0, 0.2, 0.1]], np.float32), (5, 1))
    rays = run.render_rays(o, d)
    assert np.isfinite(rays["rgb"]).all() and rays["rgb"].shape == (5, 3)
    summary = export_run(result.run.path, out / "export", loaded=run, num_points=2000, remove_outliers=False)
    assert summary


def test_trainer_generator_lives_on_the_training_device(tiny_scene, tmp_path):
    from lift3d.data.scene import load_scene
    from lift3d.model.run_folder import RunFolder
    from lift3d.train.trainer import resolve_config

    scene = load_scene(tiny_scene)
    cfg, norm = resolve_config(scene, "fast", SHORT)
    trainer = Trainer(scene, cfg, norm, RunFolder.create(tmp_path, "s", "fast"), torch.device("cpu"), progress=False)
    assert trainer.generator.device == torch.device("cpu")
    # The checkpoint says which device its generator state belongs to (a CPU state cannot seed a CUDA one).
    assert trainer.state()["rng"]["device"] == "cpu"


def test_every_random_draw_follows_the_generator_device(tiny_scene, tmp_path, checked_draws):
    _train_render_export(tiny_scene, tmp_path, "cpu")
    drawn = {name for name, _ in checked_draws}
    assert {"rand", "randperm"} <= drawn, drawn  # the check did see the batch sampler and the samplers


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a GPU")
def test_cuda_smoke_train_render_export(tiny_scene, tmp_path):
    _train_render_export(tiny_scene, tmp_path, "cuda")
