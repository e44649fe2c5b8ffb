"""Training at the extremes (docs/robustness.md, section 1): an exploding learning rate, non-finite losses
(transient and persistent), and label sets at their edges — a frame that is all void, a scene without any
thing pixel, one instance per frame.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import torch
import yaml

from lift3d.errors import TrainingDiverged
from robust_helpers import (assert_one_line_error, cli, copy_run, copy_scene, edit_json, no_temp_files, tiny,
                            tiny_flags)


def _finite_state(path) -> dict:
    state = torch.load(path, weights_only=False)
    for name, v in state["model"].items():
        assert not v.is_floating_point() or torch.isfinite(v).all(), f"{path.name}: {name} is not finite"
    return state


def test_exploding_learning_rate_stops_with_one_line_and_keeps_the_good_checkpoint(synth_scene, tmp_path, capfd):
    """lr = 1e19 (warm-up over 1000 steps, so step 1 is still sane): the parameters blow up at step 2; the
    run stops with one line, the step-1 checkpoint is finite and is what the run folder now loads."""
    out = tmp_path / "runs"
    proc = cli(capfd, "train", "--data", synth_scene, "--output-dir", out, "--quiet",
               *tiny_flags(optim={"steps": 40, "lr_grid": 1e19, "lr_mlp": 1e19, "warmup_steps": 1000,
                                  "max_bad_steps": 3},
                           trainer={"checkpoint_every": 1}))
    (run,) = out.glob("*/*/*")
    line = assert_one_line_error(proc, "train", str(run / "checkpoints"))
    assert "non-finite" in line or "not finite" in line
    assert "--resume" in line, "the message says what to do next"
    ckpts = sorted((run / "checkpoints").glob("step-*.pt"))
    assert ckpts, "the last good checkpoint must survive"
    for c in ckpts:
        _finite_state(c)
    from lift3d.model.run_folder import RunFolder

    assert RunFolder.open(run).load_latest_checkpoint()["step"] == int(ckpts[-1].stem.split("-")[1])
    assert not no_temp_files(out)


class _NaNAt:
    """Wraps ``Trainer.losses``: the total is NaN at the given steps (counted in calls, i.e. attempts), and
    the parameters seen at each call are recorded so the test can tell whether a step changed them."""

    def __init__(self, bad_calls: set[int]):
        self.bad_calls = bad_calls
        self.calls = 0
        self.snapshots: list[torch.Tensor] = []

    def install(self, monkeypatch):
        from lift3d.train import trainer as trainer_mod

        real = trainer_mod.Trainer.losses
        spy = self

        def losses(self, batch):
            spy.snapshots.append(torch.cat([p.detach().flatten() for p in self.model.parameters()]).clone())
            terms, out = real(self, batch)
            if spy.calls in spy.bad_calls:
                terms["total"] = terms["total"] * float("nan")
            spy.calls += 1
            return terms, out

        monkeypatch.setattr(trainer_mod.Trainer, "losses", losses)
        return self


def test_transient_non_finite_losses_are_skipped(synth_scene, tmp_path, monkeypatch):
    """Two NaN losses in a row (fewer than max_bad_steps): those steps change nothing and training still
    completes all its steps with finite losses logged."""
    from lift3d.train.trainer import train

    spy = _NaNAt({4, 5}).install(monkeypatch)
    result = train(synth_scene, preset="fast", output_dir=tmp_path, progress=False, print_summary=False,
                   overrides=tiny(optim={"steps": 12, "max_bad_steps": 3},
                                  trainer={"checkpoint_every": 0, "log_every": 1, "eval_images": 1}))
    assert result.steps == 12 and spy.calls == 14
    assert torch.equal(spy.snapshots[4], spy.snapshots[5]) and torch.equal(spy.snapshots[5], spy.snapshots[6])
    assert not torch.equal(spy.snapshots[3], spy.snapshots[4]), "ordinary steps do change the parameters"
    logged = [r for r in result.run.read_log() if "total" in r]
    assert [r["step"] for r in logged] == list(range(1, 13))
    assert all(math.isfinite(r["total"]) for r in logged)
    _finite_state(next(result.run.checkpoint_dir.glob("step-*.pt")))


def test_persistent_non_finite_loss_stops_and_keeps_the_last_checkpoint(synth_scene, tmp_path, monkeypatch):
    from lift3d.train.trainer import train

    _NaNAt(set(range(7, 100))).install(monkeypatch)
    with pytest.raises(TrainingDiverged, match=r"not finite \(or above 1000 x its first value\) for 3 consecutive steps at step 7") as err:
        train(synth_scene, preset="fast", output_dir=tmp_path, progress=False, print_summary=False,
              overrides=tiny(optim={"steps": 30, "max_bad_steps": 3}, trainer={"checkpoint_every": 5}))
    (ckpt,) = tmp_path.rglob("step-*.pt")
    assert ckpt.name == "step-000000005.pt" and str(ckpt.parent) in str(err.value)
    assert _finite_state(ckpt)["step"] == 5
    assert "\n" not in str(err.value)


def test_parameters_turning_non_finite_never_reach_a_checkpoint(synth_scene, tmp_path, monkeypatch):
    """An update that leaves a NaN in the weights while the loss of that step was finite (e.g. an inf
    gradient): the next checkpoint is refused (or the following NaN losses stop the run) — either way the
    last good checkpoint stays the newest file and nothing non-finite is written."""
    from lift3d.train import trainer as trainer_mod
    from lift3d.train.trainer import train

    real_step = trainer_mod.Trainer.train_step

    def train_step(self):
        out = real_step(self)
        if self.step == 6:  # the 7th step's update poisons one weight
            with torch.no_grad():
                next(self.model.parameters()).view(-1)[0] = float("nan")
        return out

    monkeypatch.setattr(trainer_mod.Trainer, "train_step", train_step)
    with pytest.raises(TrainingDiverged):
        train(synth_scene, preset="fast", output_dir=tmp_path, progress=False, print_summary=False,
              overrides=tiny(optim={"steps": 30, "max_bad_steps": 3}, trainer={"checkpoint_every": 5}))
    ckpts = sorted(tmp_path.rglob("step-*.pt"))
    assert [c.name for c in ckpts] == ["step-000000005.pt"]
    _finite_state(ckpts[0])


# ------------------------------------------------------------------------------------------ label edges
def _train_quick(root, out, **changes):
    from lift3d.train.trainer import train

    overrides = tiny(optim={"steps": 12}, trainer={"checkpoint_every": 0, "log_every": 1, "eval_images": 1})
    for section, values in changes.items():
        overrides.setdefault(section, {}).update(values)
    result = train(root, preset="fast", output_dir=out, progress=False, print_summary=False, overrides=overrides)
    logged = [r for r in result.run.read_log() if "total" in r]
    assert len(logged) == 12 and all(math.isfinite(v) for r in logged for k, v in r.items() if k != "step")
    cfg = yaml.safe_load(result.run.config_path.read_text())
    return result, cfg


def test_a_training_frame_that_is_all_void(synth_scene, tmp_path):
    root = copy_scene(synth_scene, tmp_path / "room")
    for name in ("frame_0001", "frame_0002"):
        png = root / "panoptic" / f"{name}.png"
        cv2.imwrite(str(png), np.zeros_like(cv2.imread(str(png))))
    result, cfg = _train_quick(root, tmp_path / "runs")
    assert cfg["field"]["num_semantic_classes"] >= 2
    assert math.isfinite(result.summary["eval"]["psnr"])


def _copy_with_classes(synth_scene, dst):
    """A copy of the scene, its thing category ids, and its lowest stuff id (to relabel things as)."""
    root = copy_scene(synth_scene, dst)
    meta = yaml.safe_load((root / "transforms.json").read_text())
    things = {c["id"] for c in meta["categories"] if c["isthing"]}
    return root, things, min(c["id"] for c in meta["categories"] if not c["isthing"])


def test_a_scene_without_any_thing_pixel_has_no_instance_head(synth_scene, tmp_path, capfd):
    root, things, stuff = _copy_with_classes(synth_scene, tmp_path / "room")

    def no_things(doc):
        for ann in doc["annotations"]:
            for seg in ann["segments_info"]:
                if seg["category_id"] in things:
                    seg["category_id"] = stuff

    edit_json(root / "panoptic.json", no_things)
    result, cfg = _train_quick(root, tmp_path / "runs")
    assert cfg["field"]["num_instance_channels"] == 0
    assert all("instance" not in r for r in result.run.read_log() if "total" in r)
    # The run renders and exports like any other.
    proc = cli(capfd, "export", "--run", result.run.path, "--pointcloud", "--source", "rays", "--num-points", 2000,
               "--output-dir", tmp_path / "export", "--quiet")
    assert proc.returncode == 0, proc.stderr
    from lift3d import load_labelled_points

    assert (load_labelled_points(tmp_path / "export").instance == 0).all()


def test_one_instance_per_frame(synth_scene, tmp_path):
    root, things, stuff = _copy_with_classes(synth_scene, tmp_path / "room")

    def one_thing(doc):
        for ann in doc["annotations"]:
            kept = False
            for seg in ann["segments_info"]:
                if seg["category_id"] in things:
                    if kept:
                        seg["category_id"] = stuff
                    kept = True

    edit_json(root / "panoptic.json", one_thing)
    result, cfg = _train_quick(root, tmp_path / "runs")
    assert cfg["scene"]["max_instances_per_frame"] == 1
    assert cfg["field"]["num_instance_channels"] >= 1
    assert any("instance" in r for r in result.run.read_log() if "total" in r)


def test_a_scene_whose_training_frames_are_all_void_is_a_clear_error(synth_scene, tmp_path, capfd):
    root = copy_scene(synth_scene, tmp_path / "room")
    for png in (root / "panoptic").glob("*.png"):
        cv2.imwrite(str(png), np.zeros_like(cv2.imread(str(png))))
    proc = cli(capfd, "train", "--data", root, "--output-dir", tmp_path / "runs", "--quiet", *tiny_flags())
    assert_one_line_error(proc, "train", str(root), "void")


def test_resuming_with_a_checkpoint_of_another_model_is_a_clear_error(healthy_run, tmp_path, capfd):
    run = copy_run(healthy_run, tmp_path / "run")
    ckpt = sorted((run / "checkpoints").glob("step-*.pt"))[-1]
    state = torch.load(ckpt, weights_only=False)
    key = next(k for k, v in state["model"].items() if v.ndim == 2)
    state["model"][key] = state["model"][key][:, :1].clone()  # a tensor of the wrong shape
    torch.save(state, ckpt)
    proc = cli(capfd, "train", "--resume", run, "--quiet", "--steps", 60)
    assert_one_line_error(proc, "train", "checkpoint")
