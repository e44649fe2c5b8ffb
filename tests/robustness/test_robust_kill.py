"""Nothing lost (docs/robustness.md, section 3): the real ``lift3d`` executable killed with SIGKILL during
training and during export, and two runs started at once into the same output folder.

Two ways to kill: at an arbitrary moment (as soon as the first checkpoint exists, i.e. mid-training), and
at the worst moment, inside the write of a file — the child's ``os.fsync`` is made to stall on that file so
the test can kill it with a complete temporary file on disk that was never renamed.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import torch

from lift3d.model.run_folder import RunFolder
from robust_helpers import cli, cli_env, no_temp_files, tiny, tiny_flags

#: ``python -c`` prelude: stall forever in ``os.fsync`` of any file whose name contains $LIFT3D_TEST_STALL
#: (after printing ``STALLED <path>``), then run ``lift3d`` with the remaining arguments.
STALL_IN_WRITE = r"""
import os, sys, time
pattern = os.environ["LIFT3D_TEST_STALL"]
real_fsync = os.fsync
def fsync(fd):
    try:
        name = os.readlink(f"/proc/self/fd/{fd}")
    except OSError:
        name = ""
    if pattern in os.path.basename(name):
        print("STALLED", name, flush=True)
        time.sleep(3600)
    return real_fsync(fd)
os.fsync = fsync
from lift3d.cli.main import main
sys.exit(main(sys.argv[1:]))
"""

DEADLINE = 600  # hang detector only: a child needs ~5 s of CPU, but CI cores may be shared

pytestmark = pytest.mark.skipif(not os.path.isdir("/proc/self/fd"), reason="the stall hook names files via /proc")


def _spawn(args: list, log: Path, stall: str | None = None) -> subprocess.Popen:
    env = cli_env()
    cmd = [sys.executable, "-m", "lift3d"]
    if stall is not None:
        env["LIFT3D_TEST_STALL"] = stall
        cmd = [sys.executable, "-c", STALL_IN_WRITE]
    out = open(log, "w")  # noqa: SIM115 - closed by the kernel when the child dies; the test reads the file
    return subprocess.Popen([*cmd, *map(str, args)], stdout=out, stderr=subprocess.STDOUT, env=env)


def _wait_for(condition, procs: list[subprocess.Popen], what: str):
    end = time.monotonic() + DEADLINE
    while time.monotonic() < end:
        value = condition()
        if value:
            return value
        for p in procs:
            if p.poll() is not None:
                raise AssertionError(f"the child ended (exit {p.returncode}) before {what}")
        time.sleep(0.01)
    raise AssertionError(f"timed out waiting for {what}")


def _kill(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)


def _stalled(log: Path) -> str | None:
    text = log.read_text() if log.exists() else ""
    return next((ln.split(" ", 1)[1] for ln in text.splitlines() if ln.startswith("STALLED ")), None)


def _final_eval(run: Path) -> dict:
    return [r for r in RunFolder(run).read_log() if r.get("final")][-1]["eval"]


@pytest.mark.slow
def test_kill_9_during_training_then_resume_equals_an_uninterrupted_run(synth_scene, tmp_path, capfd):
    steps, every = 80, 10  # A is killed at step ~10: 70 steps of margin for the poll to win the race
    flags = tiny_flags(optim={"steps": steps}, trainer={"checkpoint_every": every, "log_every": every})
    a_out, b_out = tmp_path / "a", tmp_path / "b"
    a = _spawn(["train", "--data", synth_scene, "--output-dir", a_out, "--quiet", *flags], tmp_path / "a.log")
    b = _spawn(["train", "--data", synth_scene, "--output-dir", b_out, "--quiet", *flags], tmp_path / "b.log",
               stall="step-000000020")
    try:
        # A: killed mid-run, at whatever it is doing once its first checkpoint exists.
        _wait_for(lambda: list(a_out.rglob("step-*.pt")), [a], "A's first checkpoint")
        _kill(a)
        # B: killed inside the write of checkpoint 20 (temp file complete, never renamed).
        stalled = _wait_for(lambda: _stalled(tmp_path / "b.log"), [b], "B stalling in the checkpoint write")
        _kill(b)
    finally:
        for p in (a, b):
            if p.poll() is None:
                _kill(p)
    assert a.returncode == -signal.SIGKILL and b.returncode == -signal.SIGKILL
    (run_a,) = a_out.glob("*/*/*")
    (run_b,) = b_out.glob("*/*/*")

    # What a kill leaves: every checkpoint file that exists loads; B's step 20 exists only as the temp file.
    for run in (run_a, run_b):
        for ckpt in run.glob("checkpoints/step-*.pt"):
            assert torch.load(ckpt, weights_only=False)["step"] == int(ckpt.stem.split("-")[1])
        assert (run / "config.yml").is_file() and (run / "transform.json").is_file()
    assert Path(stalled).name.startswith(".step-000000020.pt") and Path(stalled).exists()
    assert sorted(p.name for p in (run_b / "checkpoints").glob("step-*.pt")) == ["step-000000010.pt"]
    assert RunFolder(run_b).load_latest_checkpoint()["step"] == 10
    assert every <= RunFolder(run_a).load_latest_checkpoint()["step"] < steps

    # --resume finishes both; an uninterrupted run of the same settings is the reference.
    for run in (run_a, run_b):
        proc = cli(capfd, "train", "--resume", run, "--quiet")
        assert proc.returncode == 0, proc.stderr
    from lift3d.train.trainer import train

    ref = train(synth_scene, preset="fast", output_dir=tmp_path / "ref", progress=False, print_summary=False,
                overrides=tiny(optim={"steps": steps}, trainer={"checkpoint_every": every, "log_every": every}))
    ref_state = torch.load(ref.run.checkpoint_dir / f"step-{steps:09d}.pt", weights_only=False)
    ref_last = [r for r in ref.run.read_log() if r.get("step") == steps and "total" in r][-1]
    for run in (run_a, run_b):
        state = torch.load(run / "checkpoints" / f"step-{steps:09d}.pt", weights_only=False)
        for name, v in ref_state["model"].items():
            assert torch.allclose(state["model"][name], v, rtol=1e-4, atol=1e-5), f"{run.parent.parent.parent}: {name}"
        last = [r for r in RunFolder(run).read_log() if r.get("step") == steps and "total" in r][-1]
        assert last["total"] == pytest.approx(ref_last["total"], rel=1e-4)
        ev, ref_ev = _final_eval(run), _final_eval(ref.run.path)
        for key in ("psnr", "miou", "pq_scene"):
            assert ev[key] == pytest.approx(ref_ev[key], rel=1e-4, abs=1e-4), key


def test_kill_9_during_export_leaves_the_previous_export_readable(healthy_run, tmp_path, capfd):
    from lift3d import instances, load_labelled_points

    out = tmp_path / "export"
    args = ["export", "--run", healthy_run, "--pointcloud", "--source", "rays", "--format", "ply", "pcd", "label",
            "--output-dir", out, "--quiet"]
    first = cli(capfd, *args, "--num-points", 2000)
    assert first.returncode == 0, first.stderr
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    n_before = len(load_labelled_points(out))

    child = _spawn([*args, "--num-points", 3000], tmp_path / "export.log", stall="points.ply")
    try:
        stalled = _wait_for(lambda: _stalled(tmp_path / "export.log"), [child], "the export stalling in points.ply")
    finally:
        _kill(child)
    assert child.returncode == -signal.SIGKILL
    # The previous files are all there, byte for byte; the new points.ply exists only as a stray temp file.
    leftovers = no_temp_files(out)
    assert [p.name for p in leftovers] == [Path(stalled).name]
    assert {p.name: p.read_bytes() for p in out.iterdir() if p not in leftovers} == before
    assert len(load_labelled_points(out)) == n_before
    instances(out)
    assert len(load_labelled_points(out / "points.pcd")) == n_before
    # And the next export simply replaces it.
    again = cli(capfd, *args, "--num-points", 3000)
    assert again.returncode == 0, again.stderr
    assert len(load_labelled_points(out)) != n_before or before["points.ply"] != (out / "points.ply").read_bytes()


@pytest.mark.slow
def test_two_runs_started_together_into_one_output_dir_do_not_collide(synth_scene, tmp_path):
    out = tmp_path / "runs"
    flags = tiny_flags(optim={"steps": 10}, trainer={"checkpoint_every": 5, "log_every": 1})
    procs = [_spawn(["train", "--data", synth_scene, "--output-dir", out, "--quiet", *flags], tmp_path / f"{k}.log")
             for k in range(2)]
    for p in procs:
        p.wait(timeout=DEADLINE)
    assert [p.returncode for p in procs] == [0, 0], [(tmp_path / f"{k}.log").read_text()[-2000:] for k in range(2)]
    runs = sorted(out.glob("*/*/*"))
    assert len(runs) == 2, runs
    for run in runs:
        assert sorted(p.name for p in (run / "checkpoints").iterdir()) == ["step-000000005.pt", "step-000000010.pt"]
        steps = [r["step"] for r in RunFolder(run).read_log() if "total" in r]
        assert steps == list(range(1, 11)), "each log holds its own run's steps, once"
        assert torch.load(run / "checkpoints" / "step-000000010.pt", weights_only=False)["step"] == 10


def test_run_folder_creation_is_unique_under_a_thundering_herd(tmp_path):
    """Sixteen runs created in the same second from sixteen threads: sixteen distinct, empty run folders."""
    barrier = threading.Barrier(16)
    made: list[Path] = []

    def create():
        barrier.wait()
        made.append(RunFolder.create(tmp_path, "room", "fast").path)

    threads = [threading.Thread(target=create) for _ in range(16)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(made) == 16 and len(set(made)) == 16
    assert all((p / "checkpoints").is_dir() and not any((p / "checkpoints").iterdir()) for p in made)
