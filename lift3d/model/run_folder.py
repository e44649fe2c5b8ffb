"""The run folder (its layout: ``lift3d train --help``, docs/cli.md) and checkpoints.

``<output-dir>/<scene>/<preset>/<YYYY-MM-DD_HHMMSS>/`` holds ``config.yml`` (every setting, including what
was derived from the scene), ``transform.json`` (scene normalisation), ``checkpoints/step-000001000.pt``,
``log.jsonl`` (one JSON object per logged step / evaluation) and ``metrics.json`` (``lift3d eval``).

Checkpoints are written atomically and carry everything needed to rebuild the model (config, label
space, normalisation), so a run folder is usable even if ``config.yml`` was edited or lost.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from lift3d.errors import InputError
from lift3d.utils.atomic import save_torch_atomic

_STEP_RE = re.compile(r"step-(\d+)\.pt$")


@dataclass
class RunFolder:
    """Paths of one run."""

    path: Path

    @property
    def config_path(self) -> Path:
        return self.path / "config.yml"

    @property
    def transform_path(self) -> Path:
        return self.path / "transform.json"

    @property
    def checkpoint_dir(self) -> Path:
        return self.path / "checkpoints"

    @property
    def log_path(self) -> Path:
        return self.path / "log.jsonl"

    @property
    def metrics_path(self) -> Path:
        return self.path / "metrics.json"

    @classmethod
    def create(cls, output_dir: str | Path, scene_name: str, preset: str) -> "RunFolder":
        """Make a new, unique run folder. Two runs started in the same second get ``_1``, ``_2``, ...
        suffixes (``mkdir`` without ``exist_ok`` is atomic, so concurrent runs never share a folder)."""
        base = Path(output_dir) / scene_name / preset
        try:
            base.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise InputError(base, f"cannot create the output folder ({exc.strerror or exc})") from exc
        stamp = _dt.datetime.now().strftime("%Y-%m-%d_%H%M%S")
        for k in range(1000):
            path = base / (stamp if k == 0 else f"{stamp}_{k}")
            try:
                path.mkdir()
            except FileExistsError:
                continue
            except OSError as exc:
                raise InputError(base, f"cannot create the run folder ({exc.strerror or exc})") from exc
            (path / "checkpoints").mkdir()
            return cls(path)
        raise InputError(base, "could not find a free run folder name")

    @classmethod
    def open(cls, path: str | Path) -> "RunFolder":
        path = Path(path)
        if not path.is_dir():
            raise InputError(path, "run folder not found")
        if not (path / "checkpoints").is_dir() and not (path / "config.yml").is_file():
            raise InputError(path, "not a lift3d run folder (no config.yml or checkpoints/)")
        return cls(path)

    def checkpoints(self) -> list[Path]:
        """Checkpoint files, oldest first."""
        if not self.checkpoint_dir.is_dir():
            return []
        files = [p for p in self.checkpoint_dir.iterdir() if _STEP_RE.search(p.name)]
        return sorted(files, key=lambda p: int(_STEP_RE.search(p.name).group(1)))  # type: ignore[union-attr]

    def save_checkpoint(self, step: int, state: dict[str, Any], keep: int = 2) -> Path:
        """Write ``checkpoints/step-<step>.pt`` atomically, then prune to the ``keep`` newest."""
        path = self.checkpoint_dir / f"step-{step:09d}.pt"
        save_torch_atomic(path, state)
        for old in self.checkpoints()[:-max(1, keep)]:
            try:
                old.unlink()
            except OSError:
                pass
        return path

    def load_latest_checkpoint(self, map_location: str | torch.device = "cpu") -> dict[str, Any]:
        """The newest readable checkpoint. A corrupt newest file (e.g. from a full disk) is reported and the
        previous one is used; no readable checkpoint at all is an error naming the folder."""
        problems = []
        for path in reversed(self.checkpoints()):
            try:
                state = torch.load(path, map_location=map_location, weights_only=False)
                if not isinstance(state, dict) or "model" not in state:
                    raise ValueError("not a lift3d checkpoint")
                state["_path"] = str(path)
                if problems:
                    print(f"lift3d: warning: skipped unreadable checkpoint(s): {'; '.join(problems)}")
                return state
            except Exception as exc:  # torch raises many types on corrupt files
                problems.append(f"{path.name} ({type(exc).__name__})")
        if problems:
            raise InputError(self.checkpoint_dir, f"no readable checkpoint ({'; '.join(problems)})")
        raise InputError(self.checkpoint_dir, "no checkpoint found (was training started?)")

    def append_log(self, record: dict) -> None:
        """One JSON line per record; appended and flushed (a crash loses at most the line being written)."""
        try:
            with open(self.log_path, "a", encoding="utf-8") as f:
                f.write(json.dumps(record) + "\n")
                f.flush()
                os.fsync(f.fileno())
        except OSError as exc:  # e.g. a full disk: say which file (read_log skips a cut last line)
            raise OSError(exc.errno, exc.strerror or str(exc), str(self.log_path)) from None

    def read_log(self) -> list[dict]:
        if not self.log_path.is_file():
            return []
        out = []
        for line in self.log_path.read_text(encoding="utf-8").splitlines():
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:
                continue  # a line cut by a crash
        return out
