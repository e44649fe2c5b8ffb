"""`lift3d demo --quick` runs every stage and delivers every promised file; the summary matches metrics.json. The
README's demo block is in the format the demo prints (and, after a demo run, within tolerance of its numbers)."""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from lift3d.demo import metrics_block


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


# ------------------------------------------------------------------------------------------ the README's demo block
README = Path(__file__).resolve().parents[1] / "README.md"
#: The summary's numbers in the order metrics_block prints them: (section of summary.json, key).
BLOCK_FIELDS = [("metrics", "miou"), ("pseudo_labels", "miou"), ("metrics", "pq_scene"), ("pseudo_labels", "pq_scene"),
                ("metrics", "sq_scene"), ("metrics", "rq_scene"), ("pseudo_labels", "sq_scene"),
                ("pseudo_labels", "rq_scene"), ("metrics", "psnr"), ("points3d", "fscore"), ("points3d", "miou"),
                ("points3d", "miou_strict"), ("points3d", "pq"), ("points3d", "instance_recall"),
                ("points3d", "n_instances"), ("metrics", "render_ms_per_2048_rays")]


def _readme_block() -> list[str]:
    """The lines of README.md's demo block (the ```text block that starts with the test-views header)."""
    text = README.read_text()
    block = next(b for b in re.findall(r"```text\n(.*?)```", text, flags=re.S) if "test views" in b)
    return block.rstrip("\n").split("\n")


def _parse_block(lines: list[str]) -> dict:
    """The numbers of a printed demo block, as a summary (what metrics_block prints them from). The pattern of each
    line is metrics_block's own output for a summary of placeholder numbers, so the README and the code cannot
    drift apart in labels, order or layout."""
    placeholder = {"metrics": {}, "pseudo_labels": {}, "points3d": {}}
    for i, (section, key) in enumerate(BLOCK_FIELDS):
        placeholder[section][key] = 9000 + i if key == "n_instances" else 9000.0 + i
    template = metrics_block(placeholder)
    assert len(lines) == len(template), f"README block has {len(lines)} lines, the demo prints {len(template)}"
    values = []
    for line, pattern in zip(lines, template):
        regex = re.sub(r"90\d\d(?:\\\.\d+)?", lambda m: r"(-?\d+(?:\.\d+)?|\s*–\s*)", re.escape(pattern))
        match = re.fullmatch(regex, line)
        assert match, f"README line {line!r} is not in the demo's format {pattern!r}"
        values += match.groups()
    summary = {"metrics": {}, "pseudo_labels": {}, "points3d": {}}
    for (section, key), value in zip(BLOCK_FIELDS, values):
        value = value.strip()
        summary[section][key] = None if value == "–" else (int(value) if key == "n_instances" else float(value))
    return summary


def test_the_readme_demo_block_is_in_the_format_the_demo_prints():
    """The README shows what `make demo` printed once. Its block must be the demo's summary table: the same rows,
    labels, order and number formats (formatting, not values: the numbers move with the CPU, see below). Checked by
    reading the README's numbers back and printing them with the demo's own code."""
    lines = _readme_block()
    assert metrics_block(_parse_block(lines)) == lines


#: How far a demo run on another machine may land from the README's numbers, about twice what was seen. The
#: same scene and seed on two CPUs: PSNR and mIoU agreed to the digit (37.14 dB, 0.878, the benchmark's seed-0 run
#: of 2026-11-27 and the README's run), while PQ^scene and point PQ moved by 0.025 and point mIoU by 0.001 (an
#: issue's fresh clone: 0.898, 0.918, 0.830; the README's run: 0.923, 0.944, 0.829) — an instance match at IoU
#: 0.5 flips. Render time is a timing, not compared.
TOLERANCE = {("metrics", "miou"): 0.02, ("metrics", "psnr"): 1.0, ("metrics", "pq_scene"): 0.05,
             ("metrics", "sq_scene"): 0.05, ("metrics", "rq_scene"): 0.1, ("points3d", "fscore"): 0.01,
             ("points3d", "miou"): 0.03, ("points3d", "miou_strict"): 0.05, ("points3d", "pq"): 0.05,
             ("points3d", "instance_recall"): 0.34,
             # the pseudo-labels: half a unit of the printed digit (3 decimals, SQ and RQ 2)
             ("pseudo_labels", "miou"): 0.0005, ("pseudo_labels", "pq_scene"): 0.0005,
             ("pseudo_labels", "sq_scene"): 0.005, ("pseudo_labels", "rq_scene"): 0.005}


@pytest.mark.slow
@pytest.mark.skipif(not os.environ.get("LIFT3D_DEMO_OUT"), reason="set LIFT3D_DEMO_OUT to a finished demo folder")
def test_a_finished_demo_matches_the_readme_within_tolerance():
    """After `make demo` (or `lift3d demo --output-dir DIR`): `LIFT3D_DEMO_OUT=demo_out pytest -k readme` checks that
    the README's numbers are what the demo gives on this machine, within :data:`TOLERANCE`.

    Not run by default, because the demo cannot run inside the suite's budget: its `fast` training alone takes
    about 300 s on an idle 2-core CPU (1 200 s when the machine was shared), with evaluation, a 1M-point export
    and pictures on top, and `make test` is to stay under ~15 minutes on 2 cores. Nor could the suite compare
    exactly: floating-point results differ between CPUs, and PQ^scene of one run moves by a few hundredths when an
    instance match flips. The pseudo-labels' scores come from the synthetic scene alone and must agree to the
    printed digit; every number of the trained field within its tolerance."""
    summary = json.loads((Path(os.environ["LIFT3D_DEMO_OUT"]) / "summary.json").read_text())
    readme = _parse_block(_readme_block())
    for (section, key), tol in TOLERANCE.items():
        got, shown = summary[section][key], readme[section][key]
        assert got is not None and shown is not None and abs(got - shown) <= tol, (section, key, got, shown, tol)
    assert summary["points3d"]["n_instances"] == readme["points3d"]["n_instances"]
