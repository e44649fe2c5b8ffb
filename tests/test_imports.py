"""The layers import one way (docs/architecture.md): checked on the source, with ``ast``.

* ``render``, ``eval``, ``export`` and ``viz`` never import ``lift3d.train`` (they load runs through
  ``lift3d.model``); ``lift3d.model`` never imports the packages above it; ``lift3d.field`` imports nothing
  above it; ``lift3d.sfm`` imports nothing but ``data`` (and ``utils``, ``errors``).
* A ``lift3d`` import inside a function is allowed only where it keeps ``import lift3d`` (or ``lift3d
  --help``) cheap, and then says so in a comment (on its line or the comment lines just above it).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "lift3d"

#: package -> lift3d packages it must never import
FORBIDDEN = {
    "render": ("train",),
    "eval": ("train",),
    "export": ("train",),
    "viz": ("train",),
    "model": ("train", "eval", "export", "viz", "cli", "bench", "demo", "label", "convert", "synth"),
    "field": ("model", "render", "train", "eval", "export", "viz", "cli", "bench", "demo"),
    # geometry from the images builds on data alone: train, export and convert use it
    "sfm": ("field", "render", "model", "train", "eval", "export", "viz", "cli", "bench", "demo", "label", "convert",
            "synth"),
}


def _imports(tree: ast.AST):
    """(node, imported module name, inside a function) for every lift3d import of a module."""
    local: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            local.update(id(n) for n in ast.walk(node) if isinstance(n, (ast.Import, ast.ImportFrom)))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            # `from lift3d import train` names the package in the alias
            names = [f"{node.module}.{a.name}" if node.module == "lift3d" else node.module for a in node.names]
        else:
            continue
        for name in names:
            if name == "lift3d" or name.startswith("lift3d."):
                yield node, name, id(node) in local


def _modules():
    return sorted(p for p in PACKAGE.rglob("*.py") if "__pycache__" not in p.parts)


def _package(path: Path) -> str:
    rel = path.relative_to(PACKAGE).parts
    return rel[0].removesuffix(".py") if len(rel) > 1 else rel[0].removesuffix(".py")


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_no_upward_imports(package):
    bad = []
    for path in _modules():
        if _package(path) != package:
            continue
        for node, name, _ in _imports(ast.parse(path.read_text())):
            top = name.split(".")[1] if "." in name else ""
            if top in FORBIDDEN[package]:
                bad.append(f"{path.relative_to(PACKAGE.parent)}:{node.lineno} imports {name}")
    assert not bad, "\n".join(bad)


def test_function_local_imports_say_why():
    bad = []
    for path in _modules():
        lines = path.read_text().splitlines()
        for node, name, local in _imports(ast.parse("\n".join(lines))):
            if not local:
                continue
            comments = [lines[node.lineno - 1]]
            k = node.lineno - 2
            while k >= 0 and lines[k].strip().startswith(("#", "from ", "import ")):
                comments.append(lines[k])
                k -= 1
            if not any("#" in c and "cheap" in c.split("#", 1)[1] for c in comments):
                bad.append(f"{path.relative_to(PACKAGE.parent)}:{node.lineno} imports {name} inside a function")
    assert not bad, "function-local lift3d imports without a comment saying they keep an import cheap:\n" + \
        "\n".join(bad)


def test_the_check_finds_what_it_looks_for(tmp_path):
    """The walker sees module-level, function-local and `from lift3d import x` imports."""
    tree = ast.parse("import lift3d.train.trainer\nfrom lift3d import train\n"
                     "def f():\n    from lift3d.model.run import load_run  # keeps `import lift3d` cheap\n")
    found = [(name, local) for _, name, local in _imports(tree)]
    assert found == [("lift3d.train.trainer", False), ("lift3d.train", False), ("lift3d.model.run", True)]


def test_every_package_folder_is_a_package():
    """setuptools' find_packages skips folders without __init__.py: an installed lift3d would miss them."""
    missing = [str(d.relative_to(PACKAGE.parent)) for d in PACKAGE.rglob("*")
               if d.is_dir() and d.name != "__pycache__" and any(d.glob("*.py")) and not (d / "__init__.py").is_file()]
    assert not missing, missing


@pytest.mark.parametrize("code", [
    "import lift3d",
    "import lift3d.export",
    "import lift3d.cli.main as m; m.build_parser(None, lazy=True)",  # what `lift3d --help` builds
])
def test_cheap_imports_stay_free_of_torch(code):
    import subprocess
    import sys

    check = f"{code}\nimport sys\nassert 'torch' not in sys.modules, 'torch was imported'"
    proc = subprocess.run([sys.executable, "-c", check], capture_output=True, text=True, timeout=120,
                          cwd=PACKAGE.parent)
    assert proc.returncode == 0, proc.stderr[-2000:]
