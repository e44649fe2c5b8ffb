"""Fuzzing a valid scene folder: random byte flips, truncations, deleted files and shuffled / removed /
duplicated / retyped JSON fields (seeded). Every mutated scene must either load and train a few steps, or
fail with a clear :class:`~lift3d.errors.InputError` naming a file inside the scene — never hang, never raise
a raw exception, never leave a half-written output behind.

Runs in-process (``lift3d.train.trainer.train`` is what ``lift3d train`` calls; the one-line CLI rendering
of an InputError is covered by test_robust_bad_input_cli.py) with a per-case alarm as the hang detector.
"""

from __future__ import annotations

import contextlib
import json
import signal
import traceback
from pathlib import Path

import numpy as np
import pytest
import torch

from lift3d.data.scene import load_scene
from lift3d.errors import InputError, Lift3DError
from robust_helpers import copy_scene, no_temp_files, tiny

N_CASES = 40
CASE_TIMEOUT = 300  # seconds; a hang detector (a case needs well under a second of CPU)


class Hang(Exception):
    pass


@contextlib.contextmanager
def alarm(seconds: int):
    def on_alarm(signum, frame):
        raise Hang(f"no result after {seconds} s")

    old = signal.signal(signal.SIGALRM, on_alarm)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


# ------------------------------------------------------------------------------------------ mutations
_ODD_VALUES = [None, "x", "", -1, 0, 1e308, float("nan"), float("-inf"), [], {}, True, 3.5, [1, 2], {"a": 1},
               2**40, -(2**40)]


def _files(root: Path) -> list[Path]:
    return sorted(p for p in root.rglob("*") if p.is_file())


def _random_node(obj, rng, path=()):
    """A random path into a JSON document (a random walk that may stop at any container)."""
    while True:
        if isinstance(obj, dict) and obj:
            keys = list(obj)
        elif isinstance(obj, list) and obj:
            keys = list(range(len(obj)))
        else:
            return path
        if path and rng.random() < 0.3:
            return path
        k = keys[int(rng.integers(len(keys)))]
        obj, path = obj[k], path + (k,)


def _get(obj, path):
    for k in path:
        obj = obj[k]
    return obj


def _mutate_json(doc, rng) -> str:
    op = rng.choice(["drop", "retype", "duplicate", "shuffle", "remove"])
    path = _random_node(doc, rng)
    if not path:
        return "json: nothing to mutate"
    parent, key = _get(doc, path[:-1]), path[-1]
    target = parent[key]
    where = "/".join(map(str, path))
    if op == "drop":
        del parent[key]
        return f"json drop {where}"
    if op == "retype":
        value = _ODD_VALUES[int(rng.integers(len(_ODD_VALUES)))]
        parent[key] = value
        return f"json {where} = {value!r}"
    if isinstance(target, list) and target:
        if op == "duplicate":
            target.insert(int(rng.integers(len(target) + 1)), json.loads(json.dumps(target[int(rng.integers(len(target)))])))
            return f"json duplicate an element of {where}"
        if op == "shuffle":
            order = rng.permutation(len(target))
            target[:] = [target[i] for i in order]
            return f"json shuffle {where}"
        del target[int(rng.integers(len(target)))]
        return f"json remove an element of {where}"
    del parent[key]
    return f"json drop {where}"


def mutate(root: Path, rng: np.random.Generator) -> str:
    """Damage the scene folder at ``root`` in one random way; return what was done."""
    files = _files(root)
    jsons = [p for p in files if p.suffix == ".json"]
    op = rng.choice(["flip", "flip", "truncate", "empty", "delete", "json", "json", "json", "json"])
    target = (jsons if op == "json" else files)[int(rng.integers(len(jsons) if op == "json" else len(files)))]
    rel = target.relative_to(root)
    if op == "json":
        doc = json.loads(target.read_text())
        what = _mutate_json(doc, rng)
        target.write_text(json.dumps(doc))  # NaN/inf are written as NaN / -Infinity, as Python would
        return f"{rel}: {what}"
    data = bytearray(target.read_bytes())
    if op == "flip":
        n = int(rng.choice([1, 4, 32]))
        # Half the time hit the first 64 bytes (headers), else anywhere.
        span = min(len(data), 64) if rng.random() < 0.5 else len(data)
        for pos in rng.integers(0, max(span, 1), n):
            data[pos] ^= int(rng.integers(1, 256))
        target.write_bytes(bytes(data))
        return f"{rel}: {n} byte(s) flipped"
    if op == "truncate":
        keep = int(len(data) * rng.uniform(0.05, 0.95))
        target.write_bytes(bytes(data[:keep]))
        return f"{rel}: truncated to {keep}/{len(data)} bytes"
    if op == "empty":
        target.write_bytes(b"")
        return f"{rel}: emptied"
    target.unlink()
    return f"{rel}: deleted"


# ------------------------------------------------------------------------------------------ the fuzz run
def _check_outputs(out: Path) -> list[str]:
    """Half-written output: temp files, checkpoints that do not load, unparsable config.yml."""
    problems = [f"temp file left: {p}" for p in no_temp_files(out)]
    for ckpt in out.rglob("step-*.pt"):
        try:
            state = torch.load(ckpt, map_location="cpu", weights_only=False)
            assert "model" in state
        except Exception as exc:  # noqa: BLE001 - any failure is the finding
            problems.append(f"unloadable checkpoint {ckpt}: {exc!r}")
    import yaml

    for cfg in out.rglob("config.yml"):
        try:
            yaml.safe_load(cfg.read_text())
        except Exception as exc:  # noqa: BLE001
            problems.append(f"unparsable {cfg}: {exc!r}")
    return problems


def _inside(where: str, root: Path) -> bool:
    try:
        Path(where).resolve().relative_to(root.resolve())
        return True
    except ValueError:
        return False


@pytest.mark.slow
def test_fuzzed_scene_folders_load_and_train_or_fail_clearly(synth_scene, tmp_path, capfd):
    from lift3d.train.trainer import train

    overrides = tiny(optim={"steps": 2, "warmup_steps": 1},
                     trainer={"checkpoint_every": 0, "eval_images": 1, "log_every": 1})
    raw, unclear, half_written, noise = [], [], [], []
    outcomes = {"trained": 0, "input error": 0}
    capfd.readouterr()
    for case in range(N_CASES):
        rng = np.random.default_rng(1000 + case)
        root = copy_scene(synth_scene, tmp_path / f"case{case:02d}" / "room")
        what = mutate(root, rng)
        out = tmp_path / f"case{case:02d}" / "runs"
        try:
            with alarm(CASE_TIMEOUT):
                try:
                    train(root, preset="fast", output_dir=out, overrides=overrides, progress=False,
                          print_summary=False)
                    # Training reads the train split (and a val frame); everything else must still be
                    # either readable or a clear error.
                    load_scene(root).validate()
                    outcomes["trained"] += 1
                except InputError as exc:
                    outcomes["input error"] += 1
                    if not (_inside(exc.where, root) or exc.where.startswith("--")) or "\n" in str(exc):
                        unclear.append(f"case {case} ({what}): {exc}")
                except Lift3DError as exc:
                    unclear.append(f"case {case} ({what}): {type(exc).__name__}: {exc}")
        except Hang as exc:
            raw.append(f"case {case} ({what}): HANG {exc}")
        except Exception:  # noqa: BLE001 - a raw exception is exactly what this test looks for
            raw.append(f"case {case} ({what}):\n{traceback.format_exc(limit=-4)}")
        half_written += [f"case {case} ({what}): {p}" for p in _check_outputs(out) + _check_outputs(root)]
        # Nothing but lift3d's own warnings may reach stderr (C decoders printing there broke the one-line
        # contract of the CLI before lift3d.data.images captured them).
        noise += [f"case {case} ({what}): {ln}" for ln in capfd.readouterr().err.splitlines()
                  if ln.strip() and not ln.startswith("lift3d: warning: ")]
    report = "\n".join(raw + unclear + half_written + noise)
    print(f"fuzz outcomes over {N_CASES} cases: {outcomes}")
    assert not raw, f"raw exceptions / hangs:\n{report}"
    assert not unclear, f"errors not naming a scene file:\n{report}"
    assert not half_written, f"half-written outputs:\n{report}"
    assert not noise, f"raw output on stderr:\n{report}"
    # The fuzzer must exercise both outcomes, or it tests nothing.
    assert outcomes["trained"] >= 1 and outcomes["input error"] >= N_CASES // 3, outcomes


def test_mutations_are_seeded_and_varied(synth_scene, tmp_path):
    """The same seed damages the same way; different seeds cover every kind of damage."""
    kinds = set()
    for case in range(N_CASES):
        roots = [copy_scene(synth_scene, tmp_path / f"{side}{case}") for side in "ab"]
        a, b = (mutate(r, np.random.default_rng(1000 + case)) for r in roots)
        assert a == b
        trees = [{p.relative_to(r): p.read_bytes() for p in _files(r)} for r in roots]
        assert trees[0] == trees[1], f"case {case}: the same seed must damage the same bytes"
        assert trees[0] != {p.relative_to(synth_scene): p.read_bytes() for p in _files(synth_scene)}, a
        kinds.add(next(k for k in ("flipped", "truncated", "emptied", "deleted", "json") if k in a))
    assert kinds == {"flipped", "truncated", "emptied", "deleted", "json"}
