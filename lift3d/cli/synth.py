"""``lift3d synth``: write a synthetic labelled scene with simulated 2D segmenter noise and sensor models."""

from __future__ import annotations

import argparse

HELP = "write a synthetic labelled scene with simulated 2D segmenter noise"

DESCRIPTION = """\
Write a synthetic scene folder (docs/scene-format.md): posed images, GT panoptic maps, exact depth and 3D
points, the 2D panoptic pseudo-labels of a simulated noisy segmenter (per-frame ids, missed/merged/split
instances, class confusion, boundary errors, abstention, spurious segments, view-correlated confusions,
scores), sensor depth and optionally noisy poses; see docs/synth.md.
indoor: a furnished room (bounded); outdoor: a long street with sky (unbounded). A seed changes the scene
(room shape and size, textures, lighting, objects; street layout), the camera path (under --camera-path
auto) and every noise. --room-shape asks for rooms that are not boxes and --clutter for rooms of 30-40
things (rows of one class, thin and flat things): held-out cases for tuning. The same arguments give the
same files byte for byte; every option is recorded in transforms.json under `lift3d_synth`."""


def _pose_noise(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None


def add_parser(subparsers, verb: str) -> argparse.ArgumentParser:
    """Register ``lift3d synth`` on the CLI's subparsers."""
    # The choices come from lift3d.synth (scipy, Open3D): here, not at module level, and built only when
    # this verb runs (HELP, see lift3d.cli.main), so that `lift3d --help` stays cheap.
    from lift3d.synth.indoor import CLUTTER_LEVELS, ROOM_SHAPES
    from lift3d.synth.make import CAMERA_PATHS, KINDS
    from lift3d.synth.noise import PRESETS
    from lift3d.synth.sensors import DEPTH_MODES

    p = subparsers.add_parser(
        verb, help=HELP,
        description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--out", required=True, metavar="DIR", help="output scene folder (created)")
    p.add_argument("--kind", default="indoor", choices=KINDS, help="scene kind (default: indoor)")
    p.add_argument("--seed", type=int, default=0,
                   help="random seed of the scene, its camera path and every noise (default: 0)")
    p.add_argument("--noise", default="moderate", choices=tuple(PRESETS),
                   help="simulated segmenter errors, from easy to hard (default: moderate)")
    p.add_argument("--view-confusion", type=float, default=None, metavar="P",
                   help="share in [0, 1] of objects and stuff patches with a persistent view-dependent wrong class "
                        "(default: the --noise preset's: 0.4 for view-correlated, else 0)")
    p.add_argument("--score-informativeness", type=float, default=None, metavar="S",
                   help="how much segment scores say about correctness, in [0, 1]; 0 = drawn independently of "
                        "correctness (default: the --noise preset's: 0.3 for view-correlated, else 1)")
    p.add_argument("--camera-path", default="auto", choices=CAMERA_PATHS,
                   help="how the camera moves: orbit (indoor), walk, handheld; auto picks one from the seed "
                        "(default: auto)")
    p.add_argument("--depth", default="sensor", choices=DEPTH_MODES,
                   help="input depth maps: a structured-light sensor's (noise, holes, mm quantisation), exact, or "
                        "none (images only); exact depth is always kept as ground truth (default: sensor)")
    p.add_argument("--pose-noise", nargs=2, type=_pose_noise, default=(0.0, 0.0), metavar=("DEG", "CM"),
                   help="RMS rotation (degrees) and translation (centimetres) noise of the written poses; "
                        "rendering uses the true ones, kept as gt_transform_matrix (default: 0 0)")
    p.add_argument("--room-shape", default="auto", choices=ROOM_SHAPES,
                   help="indoor room: auto (the seed's rectangle or L, as before), box, l, polygon (5-8 walls at "
                        "non-right angles), hexagon, sloped (plane ceiling 3.6-2.2 m), vaulted (barrel vault), "
                        "round (cylinder or one curved wall), open (two rooms through a doorway, or open onto a "
                        "dark space) (default: auto)")
    p.add_argument("--clutter", default="none", choices=CLUTTER_LEVELS,
                   help="indoor things: none (6-16, as before), dense (30-40: several of a class side by side, "
                        "thin and flat things, things on tables), auto (the seed picks; dense in one room of "
                        "three) (default: none)")
    p.add_argument("--views", type=int, default=60, metavar="N", help="number of views (default: 60)")
    p.add_argument("--width", type=int, default=128, help="image width in pixels (default: 128)")
    p.add_argument("--height", type=int, default=128, help="image height in pixels (default: 128)")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Build the scene and print a short summary with the noise statistics."""
    # here, not at module level: keeps `lift3d --help` cheap
    from lift3d.synth import SynthOptions, make_scene

    options = SynthOptions(kind=args.kind, seed=args.seed, noise=args.noise, n_views=args.views, width=args.width,
                           height=args.height, camera_path=args.camera_path, depth=args.depth,
                           pose_noise=tuple(args.pose_noise), view_confusion=args.view_confusion,
                           score_informativeness=args.score_informativeness, room_shape=args.room_shape,
                           clutter=args.clutter)
    report = make_scene(args.out, options, progress=True)
    print(format_summary(report))
    return 0


def format_summary(report: dict) -> str:
    """A few lines: what was written, the content, the sensors and the simulated segmenter's statistics."""
    c, n, o = report["content"], report["noise"], report["options"]
    rates, counts = n["rates"], n["counts"]

    def pct(x) -> str:
        return "n/a" if x is None else f"{100 * x:.1f}%"

    scene = c["scene"]
    if "room" in scene:
        room = scene["room"]
        size = room["size_m"]
        variant = f" ({room['variant'].replace('_', ' ')})" if "variant" in room else ""
        what = (f"{room['shape']}{variant} room {size[0]:.1f} x {size[1]:.1f} x {size[2]:.1f} m, walls "
                f"{scene['wall_texture']['style']}, floor {scene['floor_texture']['style']}, light "
                f"{scene['lighting']['kelvin']} K")
    else:
        st = scene["street"]
        what = (f"street {2 * st['road_half_width_m']:.1f} m wide, buildings {st['building_height_m'][0]:.0f}-"
                f"{st['building_height_m'][1]:.0f} m")
    d, pn = report["depth"], report["pose_noise"]
    depth = d["mode"] + (f" ({pct(d['holes'])} holes: {pct(d['edge_holes'])} at depth edges, "
                         f"{pct(d['random_holes'])} random)" if d["mode"] == "sensor" else "")
    tv = n.get("test_views") or {}
    lines = [
        f"wrote {report['kind']} scene to {report['out']} in {report['seconds']:.1f} s: {report['n_views']} views "
        f"{report['width']}x{report['height']} (train {report['splits']['train']}, val {report['splits']['val']}, "
        f"test {report['splits']['test']}; disjoint)",
        f"  content: {what}; {c['n_things']} objects of {c['n_thing_classes']} thing classes"
        + (" (dense clutter)" if o["clutter_level"] == "dense" else "")
        + f" ({c['thin_things']} thin, {c['flat_things']} flat; {c['things_seen_in_3_views']} seen in >= 3 views), "
        f"extent "
        f"{c['extent_m']:.1f} m"
        + (f" = {c['extent_over_baseline']}x the camera baseline ({c['camera_baseline_m']:.2f} m)"
           if c["scene_box"]["type"] == "unbounded" else "")
        + f", scene box {c['scene_box']['type']}, {c['gt_points']} GT points",
        f"  cameras: {o['camera_path']} path" + (" (auto)" if o["camera_path_option"] == "auto" else "")
        + f", {o['hfov_deg']:.0f} deg field of view, >= {c['camera_clearance_m'][0]:.2f} m from surfaces; "
        f"depth {depth}; pose noise {pn['rms_deg']:.2f} deg / {pn['rms_cm']:.1f} cm RMS",
        f"  noise '{n['name']}': missed {counts['missed']}/{counts['gt_things']} things ({pct(rates['missed'])}), "
        f"confused {counts['confused']}/{counts['confusion_eligible']} segments ({pct(rates['confused'])}), "
        f"merged {counts['merged']}/{counts['merge_considered']} touching pairs ({pct(rates['merged'])}), "
        f"split {counts['split']}/{counts['split_eligible']} ({pct(rates['split'])})",
        f"    view-correlated: {pct(rates['view_confused_things'])} of visible things and "
        f"{pct(rates['view_confused_pixels'])} of pixels (view confusion {o['view_confusion']:g}); "
        f"boundary shifted {pct(rates['boundary_shifted'])} of segments, void rings {pct(rates['boundary_void'])}, "
        f"{rates['abstain_blobs_per_frame']:.2f} void blobs and {rates['spurious_per_frame']:.2f} spurious "
        f"segments per frame; void pixels {pct(n['pixels']['void_fraction'])}",
        f"    scores (informativeness {o['score_informativeness']:g}): correct {n['mean_score']['correct']}, "
        f"corrupted {n['mean_score']['corrupted']}; pseudo-label semantic accuracy "
        f"{pct(n['pixels']['semantic_accuracy'])}, mIoU {n['semantic_miou']:.3f} (strict "
        f"{n['semantic_miou_strict']:.3f}); on the test views mIoU {_num(tv.get('miou'))}, PQ^scene "
        f"{_num(tv.get('pq_scene'))}",
        f"  noise statistics: {report['paths']['noise_stats']}",
    ]
    return "\n".join(lines)


def _num(x) -> str:
    return "-" if x is None else f"{x:.3f}"
