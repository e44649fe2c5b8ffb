"""Bad input through the CLI (docs/robustness.md, section 2): every case must end with exit code 2 and ONE
stderr line ``lift3d <verb>: error: <file>: <problem>`` — no traceback, nothing printed by C libraries — and
must leave no half-written output behind.

The CLI runs in-process (``lift3d.cli.main.main``; output captured at the file-descriptor level) so the
whole table costs seconds; ``test_robust_kill.py`` runs the real ``lift3d`` executable.
"""

from __future__ import annotations

import errno
import os
import tempfile
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
import yaml

from robust_helpers import (
    assert_one_line_error,
    cli,
    copy_run,
    copy_scene,
    edit_json,
    no_temp_files,
    tiny_flags,
    tmpfs,
    writes_blocked_by_permissions,
)


# ------------------------------------------------------------------------------------------ damage
def _truncate(rel: str, keep: int):
    return lambda root: (root / rel).write_bytes((root / rel).read_bytes()[:keep])


def _flip(rel: str, pos: int):
    def damage(root):
        data = bytearray((root / rel).read_bytes())
        data[pos] ^= 0xFF
        (root / rel).write_bytes(bytes(data))
    return damage


def _write(rel: str, data: bytes):
    return lambda root: (root / rel).write_bytes(data)


def _crop(rel: str, rows: slice, cols: slice):
    def damage(root):
        img = cv2.imread(str(root / rel), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(root / rel), np.ascontiguousarray(img[rows, cols]))
    return damage


def _grey_label(rel: str):
    def damage(root):
        img = cv2.imread(str(root / rel), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(root / rel), img[..., 0])
    return damage


def _meta(change):
    return lambda root: edit_json(root / "transforms.json", change)


def _panoptic(change, rel: str = "panoptic.json"):
    return lambda root: edit_json(root / rel, change)


def _pose(value_fn):
    def change(meta):
        meta["frames"][2]["transform_matrix"] = value_fn(meta["frames"][2]["transform_matrix"])
    return _meta(change)


def _set(m, key, value):
    m[key] = value


def _segments_of(doc, name):
    return next(a for a in doc["annotations"] if a["file_name"] == name)["segments_info"]


_PNG_GARBAGE = b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 4

#: (case id, damage, file named in the message (relative to the scene), problem fragment)
SCENE_CASES = [
    ("image-truncated", _truncate("images/frame_0001.png", 200), "images/frame_0001.png", "corrupt or truncated"),
    ("image-crc-error", _flip("images/frame_0001.png", 20), "images/frame_0001.png", "CRC error"),
    ("image-empty", _write("images/frame_0001.png", b""), "images/frame_0001.png", "empty file"),
    ("image-is-text", _write("images/frame_0001.png", b"hello"), "images/frame_0001.png", "not a readable image"),
    ("image-missing", lambda r: (r / "images/frame_0003.png").unlink(), "images/frame_0003.png", "file not found"),
    ("image-size-mismatch", _crop("images/frame_0003.png", slice(None), slice(0, 20)), "images/frame_0003.png",
     "image is 20x32 but transforms.json says w=32, h=32"),
    ("label-truncated", _truncate("panoptic/frame_0001.png", 120), "panoptic/frame_0001.png", "not a readable image"),
    ("label-garbage", _write("panoptic/frame_0001.png", _PNG_GARBAGE), "panoptic/frame_0001.png",
     "not a readable image"),
    ("label-not-rgb", _grey_label("panoptic/frame_0001.png"), "panoptic/frame_0001.png", "must be 8-bit RGB"),
    ("label-size-mismatch", _crop("panoptic/frame_0001.png", slice(0, 16), slice(None)), "panoptic/frame_0001.png",
     "panoptic PNG is 32x16 but the image is 32x32"),
    ("unknown-category-id",
     _panoptic(lambda d: _segments_of(d, "frame_0001.png")[0].__setitem__("category_id", 99)),
     "panoptic.json", "unknown category id 99"),
    ("category-id-0", _meta(lambda m: m["categories"][0].__setitem__("id", 0)), "transforms.json",
     "categories[0].id: must be >= 1"),
    ("segment-missing-from-json", _panoptic(lambda d: _segments_of(d, "frame_0001.png").pop(0)),
     "panoptic/frame_0001.png", "are in the PNG but not in its segments_info"),
    ("annotation-missing",
     _panoptic(lambda d: d.__setitem__("annotations", [a for a in d["annotations"] if a["file_name"] != "frame_0005.png"])),
     "panoptic.json", "no annotation with file_name 'frame_0005.png'"),
    ("score-out-of-range", _panoptic(lambda d: _segments_of(d, "frame_0000.png")[0].__setitem__("score", 1.5)),
     "panoptic.json", "score: 1.5 is not in [0, 1]"),
    ("pose-nan", _pose(lambda m: [[float("nan")] + r[1:] if i == 0 else r for i, r in enumerate(m)]),
     "transforms.json", "frames[2].transform_matrix: not finite"),
    ("pose-inf", _pose(lambda m: [r[:3] + [float("inf")] if i == 1 else r for i, r in enumerate(m)]),
     "transforms.json", "frames[2].transform_matrix: not finite"),
    ("pose-scaled", _pose(lambda m: [[2 * v for v in r[:3]] + r[3:] if i < 3 else r for i, r in enumerate(m)]),
     "transforms.json", "frames[2].transform_matrix: not a rigid transform"),
    ("pose-mirrored", _pose(lambda m: [[-v for v in r[:1]] + r[1:] for r in m[:3]] + m[3:]),
     "transforms.json", "frames[2].transform_matrix: not a rigid transform"),
    ("pose-3x3", _pose(lambda m: [r[:3] for r in m[:3]]), "transforms.json", "must be 4x4 (got shape (3, 3))"),
    ("pose-not-numbers", _pose(lambda m: "identity"), "transforms.json", "not a 4x4 matrix of numbers"),
    ("intrinsics-nan", _meta(lambda m: m["frames"][0].__setitem__("fl_x", float("nan"))), "transforms.json",
     "frames[0].fl_x: not finite"),
    ("duplicate-frame", _meta(lambda m: m["frames"].append(dict(m["frames"][1]))), "transforms.json",
     "duplicate frame 'images/frame_0001.png'"),
    ("empty-train-split", _meta(lambda m: _set(m, "train_filenames", [])), "transforms.json",
     "train_filenames: empty split"),
    ("empty-val-split", _meta(lambda m: _set(m, "val_filenames", [])), "transforms.json", "val_filenames: empty split"),
    ("split-unknown-frame", _meta(lambda m: _set(m, "test_filenames", ["images/nope.png"])), "transforms.json",
     "'images/nope.png' is not one of the frames"),
    ("no-frames", _meta(lambda m: _set(m, "frames", [])), "transforms.json", "frames: missing or empty"),
    ("transforms-not-json", _write("transforms.json", b"{not json"), "transforms.json", "not valid JSON (line 1"),
    ("transforms-empty", _write("transforms.json", b""), "transforms.json", "not valid JSON"),
    ("transforms-a-list", _write("transforms.json", b"[]"), "transforms.json", "must hold a JSON object"),
    ("transforms-missing", lambda r: (r / "transforms.json").unlink(), "transforms.json", "file not found"),
    ("panoptic-json-not-json", _write("panoptic.json", b"{'annotations': []}"), "panoptic.json", "not valid JSON"),
    ("panoptic-json-binary", _write("panoptic.json", b"\x00\xff garbage"), "panoptic.json", "cannot be read"),
]


@pytest.mark.parametrize("damage, where, problem", [c[1:] for c in SCENE_CASES], ids=[c[0] for c in SCENE_CASES])
def test_train_on_bad_scene_fails_with_one_line(synth_scene, tmp_path, capfd, damage, where, problem):
    root = copy_scene(synth_scene, tmp_path / "room")
    damage(root)
    out = tmp_path / "runs"
    proc = cli(capfd, "train", "--data", root, "--output-dir", out, "--quiet", *tiny_flags(optim={"steps": 2}))
    line = assert_one_line_error(proc, "train", str(root / where), problem)
    assert line.count(": error: ") == 1
    # Nothing half-written: no temp files, no checkpoint of a run that never trained.
    assert not no_temp_files(tmp_path)
    assert not list(out.rglob("step-*.pt")) if out.exists() else True
    # ... and no empty run folder either (the output root itself may stay).
    assert not [p for p in out.rglob("*") if p.is_dir()] if out.exists() else True


def test_bad_ground_truth_found_after_training_keeps_the_trained_checkpoint(synth_scene, tmp_path, capfd):
    """GT labels are first read by the evaluation at the end of training: the error is one line naming the
    GT file, and the checkpoint trained before it is complete and loadable (nothing lost)."""
    root = copy_scene(synth_scene, tmp_path / "room")
    edit_json(root / "gt" / "panoptic.json", lambda d: _segments_of(d, "frame_0004.png").pop(0))
    out = tmp_path / "runs"
    proc = cli(capfd, "train", "--data", root, "--output-dir", out, "--quiet", *tiny_flags(optim={"steps": 2}))
    assert_one_line_error(proc, "train", str(root / "gt/panoptic/frame_0004.png"), "not in its segments_info")
    (ckpt,) = out.rglob("step-*.pt")
    assert torch.load(ckpt, weights_only=False)["step"] == 2
    assert not no_temp_files(tmp_path)


def test_a_corrupt_but_decodable_jpeg_is_a_warning_not_an_error(synth_scene, tmp_path, capfd):
    """A flipped byte inside JPEG data still decodes (with damage): training goes on, and the decoder's
    complaint becomes one ``lift3d: warning:`` line naming the file instead of raw libjpeg output."""
    root = copy_scene(synth_scene, tmp_path / "room")
    img = cv2.imread(str(root / "images/frame_0001.png"))
    ok, buf = cv2.imencode(".jpg", img)
    data = bytearray(buf.tobytes())
    for at in (0.4, 0.5, 0.6):  # enough flipped bytes that libjpeg notices, whatever the image
        data[int(len(data) * at)] ^= 0xFF
    (root / "images/frame_0001.png").unlink()
    (root / "images/frame_0001.jpg").write_bytes(bytes(data))

    def rename(meta):
        for key in ("train_filenames", "val_filenames", "test_filenames"):
            meta[key] = [n.replace("frame_0001.png", "frame_0001.jpg") for n in meta.get(key, [])]
        meta["frames"][1]["file_path"] = "images/frame_0001.jpg"

    edit_json(root / "transforms.json", rename)
    proc = cli(capfd, "train", "--data", root, "--output-dir", tmp_path / "runs", "--quiet",
               *tiny_flags(optim={"steps": 2}, trainer={"eval_images": 1}))
    assert proc.returncode == 0, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert lines and all(ln.startswith("lift3d: warning: ") for ln in lines), proc.stderr
    assert any("frame_0001.jpg: decoded with errors" in ln for ln in lines)


# ------------------------------------------------------------------------------------------ run folders
def _no_checkpoints(run: Path) -> None:
    for p in (run / "checkpoints").glob("*.pt"):
        p.unlink()


def _corrupt_checkpoints(run: Path) -> None:
    for p in (run / "checkpoints").glob("*.pt"):
        p.write_bytes(p.read_bytes()[:1000])


def _not_a_checkpoint(run: Path) -> None:
    for p in (run / "checkpoints").glob("*.pt"):
        torch.save([1, 2, 3], p)


def _not_a_run(run: Path) -> None:
    import shutil

    shutil.rmtree(run / "checkpoints")
    (run / "config.yml").unlink()


RUN_CASES = [
    ("no-checkpoint", _no_checkpoints, "checkpoints", "no checkpoint found"),
    ("all-checkpoints-truncated", _corrupt_checkpoints, "checkpoints", "no readable checkpoint (step-000000040.pt"),
    ("checkpoint-not-lift3d", _not_a_checkpoint, "checkpoints", "no readable checkpoint"),
    ("not-a-run-folder", _not_a_run, "", "not a lift3d run folder"),
]


def _verb_args(verb: str, run: Path, tmp: Path) -> list:
    if verb == "eval":
        return ["eval", "--run", run, "--quiet", "--timing-repeats", "0", "--no-points3d"]
    if verb == "export":
        return ["export", "--run", run, "--pointcloud", "--source", "rays", "--num-points", "2000",
                "--output-dir", tmp / "export", "--quiet"]
    if verb == "render":
        return ["render", "--run", run, "--output-dir", tmp / "renders", "--quiet"]
    return ["train", "--resume", run, "--quiet", "--steps", "44"]


@pytest.mark.parametrize("verb", ["eval", "export", "render", "train"])
@pytest.mark.parametrize("damage, where, problem", [c[1:] for c in RUN_CASES], ids=[c[0] for c in RUN_CASES])
def test_bad_run_folder_fails_with_one_line(healthy_run, tmp_path, capfd, verb, damage, where, problem):
    run = copy_run(healthy_run, tmp_path / "run")
    damage(run)
    proc = cli(capfd, *_verb_args(verb, run, tmp_path))
    assert_one_line_error(proc, verb, str(run / where) if where else str(run), problem)
    assert not (tmp_path / "export").exists() or not any((tmp_path / "export").iterdir())
    assert not no_temp_files(tmp_path)


def test_missing_run_folder_is_named(tmp_path, capfd):
    proc = cli(capfd, "eval", "--run", tmp_path / "nowhere", "--quiet")
    assert_one_line_error(proc, "eval", str(tmp_path / "nowhere"), "run folder not found")


def test_multi_line_messages_are_folded_into_one(healthy_run, tmp_path, capfd):
    """A broken config.yml on --resume: YAML's error spans four lines; the CLI prints one."""
    run = copy_run(healthy_run, tmp_path / "run")
    (run / "config.yml").write_text("field: {grid_levels: [1,\n  oops: :")
    proc = cli(capfd, "train", "--resume", run, "--quiet")
    assert_one_line_error(proc, "train", str(run / "config.yml"), "not valid YAML")


def test_checkpoint_of_another_model_is_a_clear_error(healthy_run, tmp_path, capfd):
    """A checkpoint whose weights do not fit the model it describes (edited, or from another version)."""
    run = copy_run(healthy_run, tmp_path / "run")
    for p in (run / "checkpoints").glob("*.pt"):
        state = torch.load(p, weights_only=False)
        state["model"].pop(next(k for k in state["model"] if k.endswith(".weight")))  # a real weight matrix
        torch.save(state, p)
    for verb in ("eval", "export", "render"):
        proc = cli(capfd, *_verb_args(verb, run, tmp_path))
        assert_one_line_error(proc, verb, str(run / "checkpoints" / "step-000000040.pt"),
                              "checkpoint does not match this lift3d")


@pytest.mark.parametrize("verb", ["render", "train"])
def test_a_corrupt_newest_checkpoint_falls_back_to_the_previous_one(healthy_run, tmp_path, capfd, verb):
    """Only the newest checkpoint is broken (a crash while it was written by an older, non-atomic tool):
    the previous one is used, with a warning naming the skipped file, and the command succeeds."""
    run = copy_run(healthy_run, tmp_path / "run")
    (run / "checkpoints" / "step-000000040.pt").write_bytes(b"garbage")
    proc = cli(capfd, *_verb_args(verb, run, tmp_path))
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    assert "skipped unreadable checkpoint(s): step-000000040.pt" in proc.stdout + proc.stderr
    if verb == "train":
        state = torch.load(run / "checkpoints" / "step-000000044.pt", weights_only=False)
        assert state["step"] == 44


def test_moved_scene_folder_is_named(healthy_run, tmp_path, capfd):
    run = copy_run(healthy_run, tmp_path / "run")
    cfg = yaml.safe_load((run / "config.yml").read_text())
    cfg["scene"]["data"] = str(tmp_path / "moved-away")
    (run / "config.yml").write_text(yaml.safe_dump(cfg))
    for p in (run / "checkpoints").glob("*.pt"):
        state = torch.load(p, weights_only=False)
        state["config"]["scene"]["data"] = str(tmp_path / "moved-away")
        torch.save(state, p)
    proc = cli(capfd, "eval", "--run", run, "--quiet", "--timing-repeats", "0", "--no-points3d")
    assert_one_line_error(proc, "eval", str(tmp_path / "moved-away"), "--data")
    proc = cli(capfd, "train", "--resume", run, "--quiet")
    assert_one_line_error(proc, "train", str(tmp_path / "moved-away"), "scene folder not found")


# ------------------------------------------------------------------------------------------ unwritable output
@pytest.fixture
def refuse_writes_in(monkeypatch):
    """Simulated read-only folders: creating any file below them fails with EACCES (what a chmod 0o555 folder
    does to a non-root user, and a read-only mount does to everyone)."""
    blocked: list[Path] = []
    real_mkstemp = tempfile.mkstemp

    def mkstemp(*args, dir=None, **kwargs):
        if dir is not None and any(Path(dir).resolve().is_relative_to(b) for b in blocked):
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(dir))
        return real_mkstemp(*args, dir=dir, **kwargs)

    monkeypatch.setattr(tempfile, "mkstemp", mkstemp)

    def add(folder: Path) -> Path:
        folder.mkdir(parents=True, exist_ok=True)
        blocked.append(folder.resolve())
        return folder

    return add


@pytest.mark.parametrize("verb", ["export", "render"])
def test_output_into_a_read_only_folder_simulated(healthy_run, tmp_path, capfd, refuse_writes_in, verb):
    out = refuse_writes_in(tmp_path / ("export" if verb == "export" else "renders"))
    proc = cli(capfd, *_verb_args(verb, healthy_run, tmp_path))
    assert_one_line_error(proc, verb, str(out), "Permission denied")
    assert not [p for p in out.rglob("*") if p.is_file()], "nothing written"


def test_export_into_a_really_read_only_folder(healthy_run, tmp_path, capfd):
    """The same with a real read-only folder: chmod 0o555 where that blocks writes (not root), else a
    read-only tmpfs mount (root), else skipped."""
    out = tmp_path / "export"
    if writes_blocked_by_permissions(out):
        out.chmod(0o555)
        try:
            proc = cli(capfd, *_verb_args("export", healthy_run, tmp_path))
        finally:
            out.chmod(0o755)
        assert_one_line_error(proc, "export", str(out), "not writable")
        return
    with tmpfs(out, "1m", read_only=True):
        proc = cli(capfd, *_verb_args("export", healthy_run, tmp_path))
        assert_one_line_error(proc, "export", str(out), "Read-only file system")


# ------------------------------------------------------------------------------------------ real processes
def test_debug_flag_shows_the_traceback_instead(synth_scene, tmp_path, capfd, monkeypatch):
    """The one-line form is the default; ``--debug`` (or LIFT3D_DEBUG=1) lets the exception through."""
    from lift3d.cli.main import main
    from lift3d.errors import InputError

    root = copy_scene(synth_scene, tmp_path / "room")
    (root / "transforms.json").write_text("{not json")
    args = ["train", "--data", str(root), "--output-dir", str(tmp_path / "runs"), "--quiet"]
    with pytest.raises(InputError, match="not valid JSON"):
        main(["--debug", *args])
    monkeypatch.setenv("LIFT3D_DEBUG", "1")
    with pytest.raises(InputError, match="not valid JSON"):
        main(args)


def test_the_real_executable_prints_one_line_and_exits_2(synth_scene, healthy_run, tmp_path):
    """The same contract end to end through ``python -m lift3d`` (what the console script runs): a corrupt
    PNG (whose decoder would print on fd 2 itself) and a run folder without checkpoints."""
    from robust_helpers import run_cli_many

    root = copy_scene(synth_scene, tmp_path / "room")
    _flip("panoptic/frame_0003.png", 20)(root)
    run = copy_run(healthy_run, tmp_path / "run")
    _no_checkpoints(run)
    train, export = run_cli_many([
        ["train", "--data", root, "--output-dir", tmp_path / "runs", "--quiet", *tiny_flags(optim={"steps": 2})],
        _verb_args("export", run, tmp_path),
    ])
    assert_one_line_error(train, "train", str(root / "panoptic/frame_0003.png"), "CRC error")
    assert_one_line_error(export, "export", str(run / "checkpoints"), "no checkpoint found")
