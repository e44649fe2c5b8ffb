"""``lift3d plot``: pictures of labelled geometry, of a trained run, or of the benchmark."""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from lift3d.errors import InputError

DESCRIPTION = """\
Pictures of lift3d's results, written off-screen as PNG (headless machines). --show opens a window: the
interactive 3D view instead of the PNGs for FILE.ply, the written charts for --run and --bench.

  lift3d plot FILE.ply     points.ply / mesh.ply of `lift3d export` (or any labelled PLY): instance colours
                           | class colours | legend, one PNG per --views angle -> DIR/<stem>_<view>.png;
                           --turntable adds DIR/<stem>_turntable.gif (or .mp4). Class names and colours
                           come from classes.json beside the file (or --classes), boxes from instances.json
                           (or computed from the points). Stuff on the sides facing the camera (near walls,
                           the ceiling from above) is cut away so the room's inside shows (--no-cutaway).
                           --html OUT.html writes one self-contained web page instead (WebGL, no network):
                           orbit/zoom, instance | class colours, legend; open it in any browser.
  lift3d plot --run RUN    views.png (photo | render | 2D pseudo-label | lifted panoptic | GT | depth for a
                           few test views) and curves.png (losses, PSNR, mIoU, PQ^scene over the steps).
  lift3d plot --bench DIR  pareto.png (PQ^scene, mIoU, PSNR vs training and render time per preset, against
                           the pseudo-label baseline), noise_curves.png (PQ^scene and mIoU vs label noise
                           and pose noise) and scaling.png (log-log cost vs each factor) from
                           DIR/results.json of `lift3d bench`.

An instance id has the same colour in every picture (a hash of the id, the palette of `lift3d render`'s
instance previews); stuff is drawn in grey-ish tints of its class colour in instance views.

examples:
  lift3d plot export/points.ply --views iso,top --boxes
  lift3d plot export/mesh.ply --turntable --window-size 800 400
  lift3d plot export/points.ply --html export/points.html
  lift3d plot --run outputs/room0/fast/2026-11-22_101500
  lift3d plot --bench bench_out --output-dir docs/images"""

#: ``--window-size`` limits (VTK fails or exhausts memory on absurd sizes).
_MAX_WINDOW = 8192


def add_parser(subparsers, verb: str) -> argparse.ArgumentParser:
    """Register ``lift3d plot`` on the CLI's subparsers."""
    p = subparsers.add_parser(
        verb, help="pictures of labelled points/meshes, of a trained run, or of the benchmark",
        usage="lift3d plot (FILE.ply | --run RUN | --bench DIR) [--output-dir DIR] [--show] [options]",
        description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("file", nargs="?", metavar="FILE.ply", help="labelled points.ply or mesh.ply to draw")
    p.add_argument("--run", metavar="RUN", help="a run folder of lift3d train: test views and training curves")
    p.add_argument("--bench", metavar="DIR", help="a folder with results.json of lift3d bench: Pareto, noise curves and scaling")
    p.add_argument("--output-dir", metavar="DIR",
                   help="where pictures go (default: FILE's folder/plots, RUN/plots, or the --bench DIR)")
    p.add_argument("--show", action="store_true", help="open an interactive window (needs a display)")
    g = p.add_argument_group("3D pictures (FILE.ply)")
    g.add_argument("--views", default="iso", metavar="LIST",
                   help="comma-separated camera angles: iso, top, bottom, front, back, left, right, or all "
                        "(default: iso)")
    g.add_argument("--classes", metavar="FILE", help="class table (default: classes.json beside FILE)")
    g.add_argument("--instances", metavar="FILE", help="instance boxes (default: instances.json beside FILE)")
    g.add_argument("--html", metavar="OUT.html",
                   help="write a self-contained interactive web page (WebGL, works offline) instead of PNGs")
    g.add_argument("--html-max-points", type=int, default=400_000, metavar="N",
                   help="--html: subsample point clouds beyond N points (default: 400000; meshes are kept whole)")
    g.add_argument("--boxes", action="store_true", help="draw a box and an 'id class' label per instance")
    g.add_argument("--turntable", action="store_true", help="also write an orbit animation")
    g.add_argument("--turntable-format", default="gif", choices=("gif", "mp4"),
                   help="animation format (default: gif; mp4 needs the imageio-ffmpeg package)")
    g.add_argument("--turntable-frames", type=int, default=36, metavar="N", help="frames per orbit (default: 36)")
    g.add_argument("--fps", type=int, default=12, help="turntable frames per second (default: 12)")
    g.add_argument("--window-size", type=int, nargs=2, metavar=("W", "H"),
                   help="picture size in pixels (default: 1500 650; turntable 960 400)")
    g.add_argument("--point-size", type=float, metavar="PX", help="point size in pixels (default: from density)")
    g.add_argument("--hide", default="", metavar="LIST", help="comma-separated class names or ids to leave out")
    g.add_argument("--no-cutaway", action="store_true", help="draw the walls and ceiling facing the camera too")
    g.add_argument("--up", default="auto", metavar="AXIS",
                   help="the scene's up axis: x, y, z, -x, -y, -z, or auto: the up axis the export recorded in "
                        "metadata.json beside FILE (from the training cameras), else z (default: auto)")
    g = p.add_argument_group("run pictures (--run)")
    g.add_argument("--frames", type=int, default=3, metavar="N", help="views to show (default: 3)")
    g.add_argument("--split", default="test", choices=("train", "val", "test"), help="frames to show (default: test)")
    g.add_argument("--data", metavar="DIR", help="the run's scene folder, if it moved since training")
    g.add_argument("--downscale", type=int, default=1, metavar="N", help="render N times smaller views (default: 1)")
    g.add_argument("--device", default="auto", metavar="DEV", help="auto, cpu or cuda[:N] (default: auto)")
    g.add_argument("--threads", type=int, default=None, metavar="N",
                   help="CPU threads (default: $LIFT3D_THREADS or every CPU)")
    g.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)
    return p


def _split_list(text: str) -> list[str]:
    return [t.strip() for t in str(text or "").split(",") if t.strip()]


def _check(args: argparse.Namespace) -> str:
    """Validate the combination of arguments; return the mode (file, run or bench)."""
    given = [m for m, v in (("file", args.file), ("run", args.run), ("bench", args.bench)) if v]
    if len(given) != 1:
        raise InputError("lift3d plot", "give exactly one of FILE.ply, --run RUN or --bench DIR"
                         + (f" (got {', '.join(given)})" if given else ""))
    if args.window_size is not None:
        w, h = args.window_size
        if not (16 <= w <= _MAX_WINDOW and 16 <= h <= _MAX_WINDOW):
            raise InputError("--window-size", f"expected W and H in 16..{_MAX_WINDOW}, got {w} {h}")
    if args.point_size is not None and not args.point_size > 0:
        raise InputError("--point-size", f"must be positive (got {args.point_size})")
    if args.fps < 1:
        raise InputError("--fps", f"must be at least 1 (got {args.fps})")
    if args.html and given[0] != "file":
        raise InputError("--html", "draws a FILE.ply (not --run or --bench)")
    if args.html and args.html_max_points < 1:
        raise InputError("--html-max-points", f"must be at least 1 (got {args.html_max_points})")
    if args.show:
        # here, not at module level: keeps `lift3d --help` cheap
        from lift3d.viz.points import has_display

        if not has_display():
            raise InputError("--show", "no display here (DISPLAY is not set); leave out --show to write PNGs")
    return given[0]


def run(args: argparse.Namespace) -> int:
    """Draw, then print one line per picture written."""
    mode = _check(args)
    if mode == "file":
        written = _plot_file(args)
    elif mode == "run":
        written = _plot_run(args)
    else:
        written = _plot_bench(args)
    if written:
        print(f"lift3d plot: wrote {len(written)} picture{'s' * (len(written) != 1)}")
        for path in written:
            print(f"  {path}")
    if args.show and mode != "file":
        _show_images(written)
    return 0


def _plot_file(args: argparse.Namespace) -> list[Path]:
    # here, not at module level: keeps `lift3d --help` cheap
    from lift3d.viz.points import VIEWS, PlotStyle, plot_instances, resolve_plot_up, save_turntable, save_views

    path = Path(args.file)
    if not path.is_file():
        raise InputError(path, "file not found")
    views = _split_list(args.views) or ["iso"]
    if views == ["all"]:
        views = list(VIEWS)
    for v in views:
        if v not in VIEWS:
            raise InputError("--views", f"unknown view {v!r} (choose from {', '.join(VIEWS)}, or all)")
    up = resolve_plot_up(args.up, path)
    hide = tuple(_split_list(args.hide))
    out_dir = Path(args.output_dir) if args.output_dir else path.parent / "plots"
    written: list[Path] = []
    if args.html:
        # here, not at module level: keeps `lift3d --help` cheap
        from lift3d.viz.html import write_html

        return [write_html(path, args.html, classes=args.classes, up=up, hide=hide, point_size=args.point_size,
                           max_points=args.html_max_points)]
    style = PlotStyle(boxes=args.boxes, window_size=tuple(args.window_size) if args.window_size else (1500, 650),
                      point_size=args.point_size, hide=hide, cutaway=not args.no_cutaway, up=up)
    if args.show:
        pl = plot_instances(path, style, classes=args.classes, instances=args.instances, view=views[0],
                            off_screen=False)
        pl.show(title=f"lift3d plot {path.name}")
        pl.close()
    else:
        written += save_views(path, out_dir, views, style, classes=args.classes, instances=args.instances)
    if args.turntable:
        # without --window-size, the turntable's own (smaller) default size
        spin = replace(style, window_size=tuple(args.window_size) if args.window_size else None)
        written.append(save_turntable(path, out_dir / f"{path.stem}_turntable.{args.turntable_format}", spin,
                                      classes=args.classes, instances=args.instances, frames=args.turntable_frames,
                                      fps=args.fps))
    return written


def _plot_run(args: argparse.Namespace) -> list[Path]:
    # here, not at module level: keeps `lift3d --help` cheap
    from lift3d.utils.device import set_threads
    from lift3d.viz.run import plot_run

    set_threads(args.threads)
    out = plot_run(args.run, args.output_dir, frames=args.frames, split=args.split, data=args.data,
                   device=args.device, downscale=args.downscale, progress=not args.quiet)
    return list(out.values())


def _plot_bench(args: argparse.Namespace) -> list[Path]:
    # here, not at module level: keeps `lift3d --help` cheap
    from lift3d.viz.bench import load_results, plot_noise_curves, plot_pareto, plot_scaling

    results, where = load_results(args.bench)
    bench_dir = Path(args.bench) if Path(args.bench).is_dir() else Path(args.bench).parent
    out_dir = Path(args.output_dir) if args.output_dir else bench_dir
    written = [plot_pareto(results, out_dir / "pareto.png")]
    curves = results.get("curves")
    if isinstance(curves, dict) and any(curves.values()):
        written.append(plot_noise_curves(results, out_dir / "noise_curves.png"))
    if results.get("scaling"):
        written.append(plot_scaling(results, out_dir / "scaling.png"))
    else:
        print(f"lift3d plot: {where} has no 'scaling' entries; scaling.png not drawn")
    return written


def _show_images(paths: list[Path]) -> None:
    """Open the written PNGs in matplotlib windows (the first interactive backend that loads)."""
    import matplotlib.image as mpimg
    import matplotlib.pyplot as plt

    for backend in ("QtAgg", "TkAgg", "GTK4Agg", "GTK3Agg", "WXAgg", "macosx"):
        try:
            plt.switch_backend(backend)
            break
        except (ImportError, ValueError, RuntimeError):
            continue
    else:
        raise InputError("--show", "no interactive matplotlib backend (install tkinter or PyQt); the PNGs are written")
    for path in paths:
        img = mpimg.imread(str(path))
        fig = plt.figure(figsize=(img.shape[1] / 100, img.shape[0] / 100), num=Path(path).name)
        ax = fig.add_axes((0, 0, 1, 1))
        ax.imshow(img)
        ax.set_axis_off()
    plt.show()
