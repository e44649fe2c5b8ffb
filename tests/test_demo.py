"""`lift3d demo --quick` runs every stage and delivers every promised file; the summary matches metrics.json."""

import json
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image


@pytest.mark.slow
def test_demo_quick_end_to_end(tmp_path):
    out = tmp_path / "demo"
    proc = subprocess.run([sys.executable, "-m", "lift3d", "demo", "--quick", "--output-dir", str(out)],
                          capture_output=True, text=True, timeout=900,
                          env={**__import__("os").environ, "LIFT3D_NO_PROGRESS": "1"})
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    for key, path in summary["files"].items():
        assert (tmp_path / path).exists() or __import__("pathlib").Path(path).exists(), f"missing {key}: {path}"
    for name in ("points.ply", "points.pcd", "mesh.ply", "instances.json", "classes.json", "metadata.json"):
        assert (out / "export" / name).is_file()
    pics = list((out / "pictures").glob("*.png"))
    assert len(pics) >= 3
    for p in pics:
        arr = np.asarray(Image.open(p).convert("RGB"), dtype=float)
        assert arr.std() > 5.0, f"{p.name} looks blank"
    metrics = json.loads(open(summary["files"]["metrics"]).read())
    for k, v in summary["metrics"].items():
        assert v == metrics[k] or (v is None and metrics[k] is None), k
    for k, v in summary["pseudo_labels"].items():
        assert v == metrics["pseudo_labels"][k]
    # The printed summary shows the same numbers.
    assert f"{summary['metrics']['miou']:.3f}" in proc.stdout
    assert f"{summary['pseudo_labels']['pq_scene']:.3f}" in proc.stdout
    assert set(summary["stages_seconds"]) == {"synthesise", "train", "evaluate", "export", "pictures"}
