"""``lift3d synth``: synthetic labelled scenes (indoor rooms, outdoor streets) with a simulated noisy 2D
panoptic segmenter and sensor models. See :func:`make_scene`, its :class:`SynthOptions` and ``docs/synth.md``."""

from lift3d.synth.make import SynthOptions, make_scene
from lift3d.synth.noise import PRESETS, NoiseConfig

__all__ = ["make_scene", "SynthOptions", "NoiseConfig", "PRESETS"]
