"""No function in ``lift3d/`` takes more than :data:`MAX_PARAMETERS` parameters (checked on the source, with ``ast``).

Every parameter counts: positional-only, positional, keyword-only, ``*args`` and ``**kwargs``; only the ``self`` or
``cls`` of a method does not. A function that needs more takes a typed settings dataclass for the ones that belong
together (e.g. :class:`lift3d.synth.make.SynthOptions`, :class:`lift3d.eval.evaluate.EvalOptions`).
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "lift3d"

#: Most parameters a function of the package may take.
MAX_PARAMETERS = 12


def parameter_count(node: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    """Parameters of a function definition, not counting a method's leading ``self`` or ``cls``.

    >>> parameter_count(ast.parse("def f(a, /, b, *c, d, **e): pass").body[0])
    5
    >>> parameter_count(ast.parse("def f(self, a=1): pass").body[0])
    1
    """
    a = node.args
    positional = a.posonlyargs + a.args
    count = len(positional) + len(a.kwonlyargs) + (a.vararg is not None) + (a.kwarg is not None)
    if positional and positional[0].arg in ("self", "cls"):
        count -= 1
    return count


def too_many_parameters(root: Path = PACKAGE, limit: int = MAX_PARAMETERS) -> list[str]:
    """``"<file>:<line> <name> takes <n> parameters"`` for every function under ``root`` with more than ``limit``."""
    found = []
    for path in sorted(p for p in root.rglob("*.py") if "__pycache__" not in p.parts):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = parameter_count(node)
                if n > limit:
                    found.append(f"{path.relative_to(root.parent)}:{node.lineno} {node.name} takes {n} parameters")
    return found


def test_no_function_takes_more_than_twelve_parameters():
    found = too_many_parameters()
    assert not found, (f"more than {MAX_PARAMETERS} parameters (group the ones that belong together in a typed "
                       "dataclass):\n" + "\n".join(found))


def test_the_check_sees_every_kind_of_parameter(tmp_path):
    pkg = tmp_path / "lift3d"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "sub" / "m.py").write_text(
        "def ok(a, b, c, d, e, f, g, h, i, j, k, l): pass\n"
        "def many(a, /, b, c, d, *rest, e, f, g, h, i, j, k, **more): pass\n"
        "class C:\n"
        "    def method(self, a, b, c, d, e, f, g, h, i, j, k, l): pass\n"
        "    async def run(self, a, b, c, d, e, f, g, h, i, j, k, l, m): pass\n")
    assert too_many_parameters(pkg) == ["lift3d/sub/m.py:2 many takes 13 parameters",
                                        "lift3d/sub/m.py:5 run takes 13 parameters"]
