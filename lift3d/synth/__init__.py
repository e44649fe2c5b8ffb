"""``lift3d synth``: synthetic labelled scenes (indoor room, outdoor street) with a simulated noisy 2D
panoptic segmenter. See :func:`make_scene` and ``docs/synth.md``."""

from lift3d.synth.make import make_scene
from lift3d.synth.noise import PRESETS, NoiseConfig

__all__ = ["make_scene", "NoiseConfig", "PRESETS"]
