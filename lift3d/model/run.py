"""A trained run, loaded: model, configuration, normalisation, labels and where it came from.

:func:`load_run` is the one loader every command uses (render, eval, export, plot, bench).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch

from lift3d.data.scene import Scene, load_scene
from lift3d.errors import InputError
from lift3d.model.config import Config, config_from_dict
from lift3d.model.labels import LabelSpace
from lift3d.model.normalization import SceneNormalization
from lift3d.model.panoptic import PanopticModel
from lift3d.model.run_folder import RunFolder
from lift3d.render.rays import RayGenerator
from lift3d.utils.device import resolve_device


@dataclass
class LoadedRun:
    """A trained run ready to render: model, configuration, normalisation, labels and its scene."""

    run: RunFolder
    cfg: Config
    model: PanopticModel
    norm: SceneNormalization
    labels: LabelSpace
    step: int
    device: torch.device

    def scene(self, data: str | Path | None = None) -> Scene:
        path = Path(data) if data else Path(self.cfg.scene.get("data", ""))
        if not path.is_dir():
            raise InputError(path, "the run's scene folder is gone (pass --data to point at it)")
        return load_scene(path)

    def rays(self, scene: Scene) -> RayGenerator:
        return RayGenerator(scene.cameras, self.norm.c2w_normalized(scene.cameras.c2w), self.device)


def model_from_state(state: dict, device: torch.device) -> tuple[Config, PanopticModel, SceneNormalization, LabelSpace]:
    """Rebuild the model of a checkpoint (its config may use the old flat ``field`` layout)."""
    cfg = config_from_dict(state["config"], "checkpoint")
    labels = LabelSpace.from_dict(state["labels"])
    norm = SceneNormalization.from_json(state["normalization"])
    model = PanopticModel(cfg, labels).to(device)
    model.load_state_dict(state["model"])
    model.eval()
    return cfg, model, norm, labels


def load_run(path: str | Path, device: str = "auto") -> LoadedRun:
    """Load the newest readable checkpoint of a run folder."""
    run = RunFolder.open(path)
    dev = resolve_device(device)
    state = run.load_latest_checkpoint(map_location=dev)
    try:
        cfg, model, norm, labels = model_from_state(state, dev)
    except (KeyError, RuntimeError) as exc:
        raise InputError(state.get("_path", run.checkpoint_dir), f"checkpoint does not match this lift3d ({exc})") from exc
    return LoadedRun(run, cfg, model, norm, labels, int(state["step"]), dev)
