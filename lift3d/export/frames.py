"""The export's output frames: world (the input poses' frame) or normalised (the field's coordinates).

Examples
--------
>>> import numpy as np
>>> t = np.diag([2.0, 2.0, 2.0, 1.0]); t[:3, 3] = 1.0
>>> to_frame(np.array([[0.5, 0.0, -0.5]]), t, "world").tolist(), to_frame(np.zeros((1, 3)), t, "normalized").tolist()
([[2.0, 1.0, 0.0]], [[0.0, 0.0, 0.0]])
"""

from __future__ import annotations

import numpy as np

from lift3d.errors import InputError
from lift3d.model.normalization import SceneNormalization

#: The output frames, the default first.
FRAMES = ("world", "normalized")


def world_from_normalized(norm: SceneNormalization) -> np.ndarray:
    """4×4 matrix taking normalised coordinates to world coordinates (inverse of ``norm.matrix``)."""
    return np.linalg.inv(norm.matrix)


def to_frame(x_normalized: np.ndarray, transform: np.ndarray, frame: str) -> np.ndarray:
    """Normalised points → the export frame (``world`` applies ``transform``; ``normalized`` keeps them)."""
    x = np.asarray(x_normalized, np.float64)
    if frame == "normalized":
        return x
    return x @ transform[:3, :3].T + transform[:3, 3]


def length_to_frame(length_normalized: float, norm: SceneNormalization, frame: str) -> float:
    """A length in normalised units, in the export frame's units."""
    return float(length_normalized) if frame == "normalized" else float(length_normalized) / float(norm.scale)


def check_frame(frame: str) -> None:
    """An :class:`InputError` naming ``--frame`` unless ``frame`` is one of :data:`FRAMES`."""
    if frame not in FRAMES:
        raise InputError("--frame", f"unknown frame {frame!r} (world or normalized)")
