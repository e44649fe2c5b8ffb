"""The JSON side files of every export: ``classes.json``, ``instances.json``, ``metadata.json`` (and the
writer of ``scene_graph.json`` lives in :mod:`lift3d.export.scene_graph`). Every writer is atomic
(:mod:`lift3d.utils.atomic`): a failure never leaves a partial file behind.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from lift3d.utils.atomic import write_json_atomic


def class_table(categories, semantic_ids=None) -> list[dict[str, Any]]:
    """``classes.json`` rows ``{id, name, isthing, color}`` for the scene's categories.

    Parameters
    ----------
    categories : iterable of lift3d.data.scene.Category or dict
    semantic_ids : iterable of int, optional
        The categories the field predicts; others are listed with ``"predicted": false``.

    Examples
    --------
    >>> class_table([{"id": 2, "name": "chair", "isthing": 1, "color": [1, 2, 3]}])
    [{'id': 2, 'name': 'chair', 'isthing': True, 'color': [1, 2, 3], 'predicted': True}]
    """
    predicted = None if semantic_ids is None else {int(i) for i in semantic_ids}
    rows = []
    for c in categories:
        d = c if isinstance(c, dict) else c.to_json()
        cid = int(d["id"])
        rows.append({"id": cid, "name": str(d["name"]), "isthing": bool(d["isthing"]),
                     "color": [int(v) for v in d.get("color", (128, 128, 128))],
                     "predicted": predicted is None or cid in predicted})
    return sorted(rows, key=lambda r: r["id"])


def write_classes_json(path: str | Path, classes: list[dict[str, Any]]) -> None:
    """``classes.json``: ``{"void": 0, "classes": [...]}`` (atomically)."""
    write_json_atomic(path, {"void": 0, "note": "semantic id 0 is void (never exported); instance 0 is stuff",
                             "classes": classes})


def write_instances_json(path: str | Path, records: list[dict[str, Any]], *, frame: str, units: str,
                         source: str) -> None:
    """``instances.json``: ``{"frame", "units", "source", "instances": [...]}`` (atomically)."""
    write_json_atomic(path, {"frame": frame, "units": units, "source": source,
                             "obb_convention": "corners = center + rotation @ (extent / 2 * [±1, ±1, ±1])",
                             "instances": records})


def write_metadata_json(path: str | Path, metadata: dict[str, Any]) -> None:
    """``metadata.json`` (atomically)."""
    write_json_atomic(path, metadata)
