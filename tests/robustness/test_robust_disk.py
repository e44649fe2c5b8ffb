"""A disk that fills up (docs/robustness.md, section 2): a one-line error naming the file, exit code 2, no
half-written file, and what was there before (previous export, last checkpoint, metrics) intact.

Simulated in every environment by making the atomic writer's ``write`` fail with ENOSPC after part of the
data (``robust_helpers.full_disk``); repeated on a real, tiny tmpfs where the test may mount one.
"""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path

import pytest
import torch

from robust_helpers import (
    assert_one_line_error,
    cli,
    copy_run,
    full_disk,
    no_temp_files,
    tiny_flags,
    tmpfs,
)


def _export_args(run: Path, out: Path, n: int = 2000) -> list:
    return ["export", "--run", run, "--pointcloud", "--source", "rays", "--num-points", n, "--format", "ply", "pcd",
            "--output-dir", out, "--quiet"]


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


def test_disk_full_during_export_keeps_the_previous_export(healthy_run, tmp_path, capfd):
    out = tmp_path / "export"
    first = cli(capfd, *_export_args(healthy_run, out, 3000))
    assert first.returncode == 0, first.stderr
    before = _snapshot(out)
    assert {"points.ply", "points.pcd", "metadata.json"} <= set(before)
    with full_disk(free_bytes=1024, match="points.ply") as disk:  # the header fits, the points do not
        proc = cli(capfd, *_export_args(healthy_run, out, 1500))
    assert disk.failed, "the simulated disk was never hit"
    assert_one_line_error(proc, "export", str(out / "points.ply"), "No space left on device")
    assert _snapshot(out) == before, "the previous export must be untouched, file by file"
    assert not no_temp_files(out)
    from lift3d import load_labelled_points

    assert len(load_labelled_points(out)) > 0


def test_disk_full_at_a_checkpoint_keeps_the_last_good_one(synth_scene, healthy_run, tmp_path, capfd):
    """Checkpoints every 10 steps and room for one: step 10 is written, step 20 fails half-way. The run
    stops with one line naming step-000000020.pt; step 10 loads; freeing space and --resume finishes."""
    # the smallest: the final checkpoint also holds the occupancy grid the renderer uses, those before do not
    ckpt_size = min(p.stat().st_size for p in (healthy_run / "checkpoints").glob("*.pt"))
    out = tmp_path / "runs"
    flags = tiny_flags(optim={"steps": 30}, trainer={"checkpoint_every": 10})
    with full_disk(free_bytes=int(ckpt_size * 1.5), match="step-") as disk:
        proc = cli(capfd, "train", "--data", synth_scene, "--output-dir", out, "--quiet", *flags)
    assert disk.failed
    (run,) = out.glob("*/*/*")
    assert_one_line_error(proc, "train", str(run / "checkpoints" / "step-000000020.pt"), "No space left on device")
    assert sorted(p.name for p in (run / "checkpoints").iterdir()) == ["step-000000010.pt"], "no partial file"
    assert torch.load(run / "checkpoints" / "step-000000010.pt", weights_only=False)["step"] == 10
    proc = cli(capfd, "train", "--resume", run, "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert torch.load(run / "checkpoints" / "step-000000030.pt", weights_only=False)["step"] == 30


def test_disk_full_while_writing_metrics_keeps_the_old_metrics(healthy_run, tmp_path, capfd):
    run = copy_run(healthy_run, tmp_path / "run")
    (run / "metrics.json").write_text(json.dumps({"psnr": 1.0}))
    with full_disk(free_bytes=100, match="metrics.json"):
        proc = cli(capfd, "eval", "--run", run, "--quiet", "--timing-repeats", "0", "--no-points3d")
    assert_one_line_error(proc, "eval", str(run / "metrics.json"), "No space left on device")
    assert json.loads((run / "metrics.json").read_text()) == {"psnr": 1.0}
    assert not no_temp_files(run)


@pytest.mark.skipif(not os.path.isdir("/proc/self/fd"), reason="needs /proc to tell the log's file descriptor")
def test_disk_full_while_appending_to_the_training_log_is_one_line(synth_scene, tmp_path, capfd, monkeypatch):
    """``log.jsonl`` is appended, not written atomically: an ENOSPC there is an ordinary OSError, which the
    CLI still reports as one line naming the file (the net in ``lift3d.cli.main``)."""
    import lift3d.model.run_folder as run_module

    real_fsync = os.fsync

    def fsync(fd):  # the disk fills while the log line is flushed; the file name is only known to append_log
        if os.readlink(f"/proc/self/fd/{fd}").endswith("log.jsonl"):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real_fsync(fd)

    monkeypatch.setattr(run_module.os, "fsync", fsync)
    proc = cli(capfd, "train", "--data", synth_scene, "--output-dir", tmp_path / "runs", "--quiet",
               *tiny_flags(optim={"steps": 4}, trainer={"log_every": 2}))
    assert_one_line_error(proc, "train", "log.jsonl", "No space left on device")


def test_a_real_full_tmpfs(synth_scene, healthy_run, tmp_path, capfd):
    """The same on a real 4.5 MB filesystem (skipped where tmpfs cannot be mounted): training fills it at
    the second checkpoint, export into a 32 kB one fails on the point cloud; one line each, no temp files,
    and the checkpoint that fitted loads."""
    # the smallest: the final checkpoint also holds the occupancy grid the renderer uses, those before do not
    ckpt_size = min(p.stat().st_size for p in (healthy_run / "checkpoints").glob("*.pt"))
    mnt = tmp_path / "small"
    with tmpfs(mnt, f"{int(ckpt_size * 1.5) // 1024}k"):
        proc = cli(capfd, "train", "--data", synth_scene, "--output-dir", mnt, "--quiet",
                   *tiny_flags(optim={"steps": 30}, trainer={"checkpoint_every": 10, "log_every": 10}))
        assert_one_line_error(proc, "train", str(mnt), "No space left on device")
        ckpts = list(mnt.rglob("step-*.pt"))
        assert [p.name for p in ckpts] == ["step-000000010.pt"]
        assert torch.load(ckpts[0], weights_only=False)["step"] == 10
        assert not no_temp_files(mnt)
    with tmpfs(mnt, "32k"):
        proc = cli(capfd, *_export_args(healthy_run, mnt / "export"))
        assert_one_line_error(proc, "export", str(mnt / "export"), "No space left on device")
        assert not no_temp_files(mnt)
