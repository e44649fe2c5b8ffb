"""Measure lift3d's geometry from images (sparse triangulation, dense plane sweep) against exact depth.

Developer script behind the tables of docs/sfm.md. For each scene folder (made by ``lift3d synth``, which
ships exact depth maps — ``gt_depth_file_path`` — and ``gt/points.ply``), it runs the pipeline on the ``train`` frames and reports:

* sparse: points, observations, track length, reprojection error; the fraction of points within 1 cm,
  3 cm and 1 % of the scene diagonal of the true surface (point-to-plane distance to the GT point cloud,
  point-to-point where the nearest GT point is farther than two GT spacings); the per-observation z-depth
  error against the exact depth map, and how often it is within 2 sigma; observations per class;
* dense: per pixel, the same thresholds on |z - z_true|, coverage (pixels with depth) per class;
* seconds per stage.

    python tools/sfm_benchmark.py /tmp/indoor1 /tmp/indoor2 --dense --json out.json
    python tools/sfm_benchmark.py /tmp/indoor7 --set tracks.min_views=4 --set matching.guided=false
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from lift3d.data.scene import Scene, load_scene  # noqa: E402
from lift3d.sfm import SfmConfig, plane_sweep_scene, triangulate_scene  # noqa: E402

# Class groups reported for indoor scenes (synthetic category names); other scenes report per category.
INDOOR_GROUPS = {"walls": ("wall", "window"), "floor": ("floor", "rug"), "ceiling": ("ceiling",)}


def apply_settings(cfg: SfmConfig, settings: list[str]) -> SfmConfig:
    """``section.field=value`` strings applied to a config (types from the current values)."""
    for item in settings:
        key, value = item.split("=", 1)
        section, name = key.split(".", 1)
        obj = getattr(cfg, section)
        cur = getattr(obj, name)
        if isinstance(cur, bool):
            val = value.lower() in ("1", "true", "yes")
        else:
            val = type(cur)(value)
        setattr(obj, name, val)
    return cfg


def bilinear(depth: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Depth at continuous pixel positions (bilinear) and whether the 2x2 neighbourhood is one smooth surface
    (all valid, spread below 5 %): elsewhere (depth edges) the exact depth at a sub-pixel position is
    undefined and the observation is not scored."""
    x, y = uv[:, 0] - 0.5, uv[:, 1] - 0.5
    h, w = depth.shape
    x0 = np.clip(np.floor(x).astype(int), 0, w - 2)
    y0 = np.clip(np.floor(y).astype(int), 0, h - 2)
    fx, fy = np.clip(x - x0, 0, 1), np.clip(y - y0, 0, 1)
    q = np.stack([depth[y0, x0], depth[y0, x0 + 1], depth[y0 + 1, x0], depth[y0 + 1, x0 + 1]], 1)
    wts = np.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], 1)
    ok = (q.min(1) > 0) & ((q.max(1) - q.min(1)) < 0.05 * q.max(1))
    return (q * wts).sum(1), ok


class Surface:
    """The true surface as the GT point cloud with PCA normals, for point-to-surface distances."""

    def __init__(self, xyz: np.ndarray):
        self.xyz = xyz
        self.tree = cKDTree(xyz)
        d, idx = self.tree.query(xyz, k=10)
        self.spacing = float(np.median(d[:, 1]))
        nb = xyz[idx] - xyz[idx].mean(1, keepdims=True)
        _, _, vt = np.linalg.svd(nb, full_matrices=False)
        self.normals = vt[:, -1, :]

    def distance(self, pts: np.ndarray) -> np.ndarray:
        if len(pts) == 0:
            return np.zeros(0)
        d, idx = self.tree.query(pts, k=3)
        plane = np.abs(np.einsum("nkj,nkj->nk", pts[:, None, :] - self.xyz[idx], self.normals[idx])).min(1)
        return np.where(d[:, 0] <= 2 * self.spacing, plane, d[:, 0])


def true_depth(scene: Scene, i: int) -> np.ndarray:
    """The exact depth of frame ``i``: ``gt_depth_file_path`` when the scene has it (``lift3d synth`` writes
    sensor-like depth as ``depth_file_path`` by default), else ``depth_file_path``."""
    d = scene.gt_depth(i)
    return scene.depth(i) if d is None else d


def class_groups(scene: Scene) -> dict[str, set[int]]:
    names = {c.name: c.id for c in scene.categories}
    if all(n in names for n in ("wall", "floor", "ceiling")):
        groups = {g: {names[n] for n in ns if n in names} for g, ns in INDOOR_GROUPS.items()}
        groups["objects"] = set(scene.thing_ids)
        return groups
    return {c.name: {c.id} for c in scene.categories}


def fractions(err: np.ndarray, diag: float) -> dict[str, float]:
    if len(err) == 0:
        return {"1cm": float("nan"), "3cm": float("nan"), "1%diag": float("nan")}
    return {"1cm": float((err < 0.01).mean()), "3cm": float((err < 0.03).mean()),
            "1%diag": float((err < 0.01 * diag).mean())}


def sparse_metrics(scene: Scene, sp, surface: Surface, diag: float) -> dict:
    names = [f.name for f in scene.frames]
    dist = surface.distance(sp.xyz)
    dz, ok_all, sig = [], [], []
    groups = class_groups(scene)
    pix_per_group = {g: 0 for g in groups}
    obs_per_group = {g: 0 for g in groups}
    covered = []
    for k, name in enumerate(sp.frame_names):
        fi = names.index(name)
        obs = sp.frame_observations(k)
        sem = scene.gt_labels(fi).semantic
        h, w = sem.shape
        for g, ids in groups.items():
            pix_per_group[g] += int(np.isin(sem, list(ids)).sum())
        covered.append(len(obs["uv"]) / (h * w))
        if len(obs["uv"]) == 0:
            continue
        z, ok = bilinear(true_depth(scene, fi), obs["uv"])
        dz.append(obs["depth"] - z)
        ok_all.append(ok)
        sig.append(obs["sigma"])
        c = np.clip(obs["uv"][:, 0].astype(int), 0, w - 1)
        r = np.clip(obs["uv"][:, 1].astype(int), 0, h - 1)
        s = sem[r, c]
        for g, ids in groups.items():
            obs_per_group[g] += int(np.isin(s, list(ids)).sum())
    dz = np.concatenate(dz) if dz else np.zeros(0)
    ok = np.concatenate(ok_all) if ok_all else np.zeros(0, bool)
    sig = np.concatenate(sig) if sig else np.zeros(0)
    a = np.abs(dz[ok])
    n_obs = max(len(sp.obs_point), 1)
    return {
        "points": len(sp), "observations": int(len(sp.obs_point)),
        "median_track_length": float(np.median(sp.track_length)) if len(sp) else 0.0,
        "median_reprojection_px": sp.median_error,
        "surface": fractions(dist, diag),
        "median_surface_distance": float(np.median(dist)) if len(dist) else float("nan"),
        "obs_depth": {**fractions(a, diag), "median_abs": float(np.median(a)) if len(a) else float("nan"),
                      "within_2sigma": float((a < 2 * sig[ok]).mean()) if len(a) else float("nan"),
                      "scored": int(ok.sum())},
        "obs_per_frame": float(len(sp.obs_point) / max(len(sp.frame_names), 1)),
        "pixel_coverage": float(np.mean(covered)) if covered else 0.0,
        "classes": {g: {"pixel_share": pix_per_group[g] / max(sum(pix_per_group.values()), 1),
                        "obs_share": obs_per_group[g] / n_obs,
                        "obs_per_1000px": 1000 * obs_per_group[g] / max(pix_per_group[g], 1)}
                    for g in groups},
        "dropped": sp.info.get("dropped", {}), "seconds": sp.info.get("seconds", {}),
    }


def dense_metrics(scene: Scene, dense, diag: float) -> dict:
    names = [f.name for f in scene.frames]
    groups = class_groups(scene)
    errs, sigs, cover = [], [], []
    g_pix = {g: 0 for g in groups}
    g_cov = {g: 0 for g in groups}
    g_err = {g: [] for g in groups}
    for k, name in enumerate(dense.frame_names):
        fi = names.index(name)
        d, s = dense.depth[k], dense.sigma[k]
        gt = true_depth(scene, fi)
        sem = scene.gt_labels(fi).semantic
        valid = d > 0
        scored = valid & (gt > 0)
        cover.append(valid.mean())
        e = np.abs(d[scored] - gt[scored])
        errs.append(e)
        sigs.append(s[scored])
        for g, ids in groups.items():
            m = np.isin(sem, list(ids))
            g_pix[g] += int(m.sum())
            g_cov[g] += int((m & valid).sum())
            g_err[g].append(np.abs(d[m & scored] - gt[m & scored]))
    e = np.concatenate(errs) if errs else np.zeros(0)
    s = np.concatenate(sigs) if sigs else np.zeros(0)
    return {
        "coverage": float(np.mean(cover)) if cover else 0.0,
        "depth": {**fractions(e, diag), "median_abs": float(np.median(e)) if len(e) else float("nan"),
                  "within_2sigma": float((e < 2 * s).mean()) if len(e) else float("nan")},
        "classes": {g: {"pixel_share": g_pix[g] / max(sum(g_pix.values()), 1),
                        "coverage": g_cov[g] / max(g_pix[g], 1),
                        **fractions(np.concatenate(g_err[g]) if g_err[g] else np.zeros(0), diag)}
                    for g in groups},
        "seconds": dense.info.get("seconds", {}),
    }


def measure(path: str, cfg: SfmConfig, dense: bool) -> dict:
    scene = load_scene(path)
    gt = scene.gt_points()
    surface = Surface(gt["xyz"].astype(np.float64))
    diag = float(np.linalg.norm(gt["xyz"].max(0) - gt["xyz"].min(0)))
    t0, c0 = time.perf_counter(), time.process_time()
    sp = triangulate_scene(scene, config=cfg)
    sparse_s, sparse_cpu = time.perf_counter() - t0, time.process_time() - c0
    out = {"scene": path, "views": int(len(scene.split("train"))),
           "size": f"{int(scene.cameras.width[0])}x{int(scene.cameras.height[0])}", "diag": diag,
           "sparse": sparse_metrics(scene, sp, surface, diag), "sparse_seconds": sparse_s,
           "sparse_cpu_seconds": sparse_cpu,
           "warnings": sp.info.get("warnings", [])}
    if dense:
        t0, c0 = time.perf_counter(), time.process_time()
        dd = plane_sweep_scene(scene, config=cfg, sparse=sp)
        out["dense_seconds"], out["dense_cpu_seconds"] = time.perf_counter() - t0, time.process_time() - c0
        out["dense"] = dense_metrics(scene, dd, diag)
    return out


def pct(x: float) -> str:
    return "–" if x != x else f"{100 * x:.1f} %"


def report(results: list[dict]) -> str:
    lines = ["| scene | views | points | obs/frame | track | reproj px | ≤1 cm | ≤3 cm | ≤1 % diag | obs |dz| "
             "median | within 2σ | seconds (CPU) |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        s = r["sparse"]
        lines.append(
            f"| {Path(r['scene']).name} | {r['views']} × {r['size']} | {s['points']} | {s['obs_per_frame']:.0f} | "
            f"{s['median_track_length']:.0f} | {s['median_reprojection_px']:.2f} | {pct(s['surface']['1cm'])} | "
            f"{pct(s['surface']['3cm'])} | {pct(s['surface']['1%diag'])} | "
            f"{100 * s['obs_depth']['median_abs']:.1f} cm | {pct(s['obs_depth']['within_2sigma'])} | "
            f"{r['sparse_seconds']:.1f} ({r['sparse_cpu_seconds']:.1f}) |")
    if any("dense" in r for r in results):
        lines += ["", "| scene | coverage | ≤1 cm | ≤3 cm | ≤1 % diag | median |dz| | within 2σ | seconds (CPU) |",
                  "|---|---|---|---|---|---|---|---|"]
        for r in results:
            if "dense" not in r:
                continue
            d = r["dense"]
            lines.append(f"| {Path(r['scene']).name} | {pct(d['coverage'])} | {pct(d['depth']['1cm'])} | "
                         f"{pct(d['depth']['3cm'])} | {pct(d['depth']['1%diag'])} | "
                         f"{100 * d['depth']['median_abs']:.1f} cm | {pct(d['depth']['within_2sigma'])} | "
                         f"{r['dense_seconds']:.1f} ({r['dense_cpu_seconds']:.1f}) |")
    lines += ["", "| scene | class | pixels | sparse obs share | sparse obs / 1000 px | dense coverage | dense ≤3 cm |",
              "|---|---|---|---|---|---|---|"]
    for r in results:
        for g, c in r["sparse"]["classes"].items():
            d = r.get("dense", {}).get("classes", {}).get(g, {})
            lines.append(f"| {Path(r['scene']).name} | {g} | {pct(c['pixel_share'])} | {pct(c['obs_share'])} | "
                         f"{c['obs_per_1000px']:.1f} | {pct(d.get('coverage', float('nan')))} | "
                         f"{pct(d.get('3cm', float('nan')))} |")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenes", nargs="+")
    ap.add_argument("--dense", action="store_true")
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.FIELD=VALUE")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    cfg = apply_settings(SfmConfig(), args.set)
    results = [measure(s, cfg, args.dense) for s in args.scenes]
    print(report(results))
    for r in results:
        print(Path(r["scene"]).name, "dropped", r["sparse"]["dropped"], "seconds", r["sparse"]["seconds"],
              r.get("dense", {}).get("seconds", ""), r["warnings"])
    if args.json:
        args.json.write_text(json.dumps({"config": dataclasses.asdict(cfg), "results": results}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
