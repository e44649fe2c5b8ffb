"""``lift3d <verb>``: one entry point, a module per verb (``lift3d/cli/<verb>.py`` with ``add_parser``).

Verb modules import their implementation inside ``run`` so that ``lift3d --help`` stays cheap. A verb whose
parser itself is expensive to build (``train``: its flags come from the torch-backed run configuration;
``synth``: its choices from the scene generator) sets a module constant ``HELP`` (its one-line help); the
parser then lists it without building it unless that verb is the one being run.

Bad input (:class:`~lift3d.errors.Lift3DError`) is printed as one line with exit code 2; ``--debug`` shows the
traceback instead.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from lift3d import __version__
from lift3d.errors import Lift3DError
from lift3d.utils.threads import choose_openmp_waiting

# Verb → module under lift3d.cli, in the order of the pipeline (docs/cli.md). A verb is listed only once it works.
VERBS = {
    "demo": "demo",
    "synth": "synth",
    "convert": "convert",
    "triangulate": "triangulate",
    "train": "train",
    "render": "render",
    "eval": "evaluate",
    "export": "export",
    "plot": "plot",
    "label": "label",
    "bench": "bench",
}


def build_parser(verb: str | None = None, *, lazy: bool = False) -> argparse.ArgumentParser:
    """The ``lift3d`` parser. With ``lazy``, verbs other than ``verb`` whose module sets ``HELP`` get a stub
    sub-parser (listed in ``--help``, never parsed with): ``lift3d --help`` builds no expensive parser."""
    parser = argparse.ArgumentParser(
        prog="lift3d",
        description="3D panoptic labelling: lift noisy 2D panoptic predictions into a 3D-consistent panoptic "
        "radiance field, then render, evaluate and export labelled point clouds and meshes.",
    )
    parser.add_argument("--version", action="version", version=f"lift3d {__version__}")
    parser.add_argument("--debug", action="store_true", help="show full tracebacks instead of one-line errors")
    sub = parser.add_subparsers(dest="verb", metavar="<verb>")
    for name, module in VERBS.items():
        try:
            mod = importlib.import_module(f"lift3d.cli.{module}")
        except ModuleNotFoundError as exc:
            if exc.name == f"lift3d.cli.{module}":
                continue  # not built yet: absent rather than pretending to work
            raise
        if lazy and name != verb and getattr(mod, "HELP", None):
            sub.add_parser(name, help=mod.HELP)
            continue
        p = mod.add_parser(sub, name)
        p.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                       help="show full tracebacks instead of one-line errors")
    return parser


def one_line(message: str) -> str:
    """A message folded onto one line (YAML and torch errors span several).

    >>> one_line("config.yml: not valid YAML (while parsing\\n  in line 1\\n)")
    'config.yml: not valid YAML (while parsing | in line 1 | )'
    """
    return " | ".join(part.strip() for part in message.splitlines() if part.strip())


def main(argv: list[str] | None = None) -> int:
    # First, before any verb (or its parser) loads torch: OpenMP reads how its threads wait only then.
    choose_openmp_waiting()
    argv = list(sys.argv[1:] if argv is None else argv)
    verb = next((a for a in argv if not a.startswith("-")), None)  # the top level has no option with a value
    parser = build_parser(verb, lazy=True)
    args = parser.parse_args(argv)
    if not getattr(args, "verb", None):
        parser.print_help()
        return 2
    debug = bool(getattr(args, "debug", False)) or os.environ.get("LIFT3D_DEBUG", "") not in ("", "0")
    try:
        rc = args.func(args)
        return int(rc or 0)
    except Lift3DError as exc:
        if debug:
            raise
        print(f"lift3d {args.verb}: error: {one_line(str(exc))}", file=sys.stderr)
        return 2
    except OSError as exc:
        # The environment, not a bug: a full disk, a read-only or vanished folder, a permission. Writers that
        # know their file raise InputError; this is the net for the rest (e.g. appends to a log).
        if debug:
            raise
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"lift3d {args.verb}: error: {where}{one_line(exc.strerror or str(exc))}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"lift3d {args.verb}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
