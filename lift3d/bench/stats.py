"""Statistics of ``lift3d bench``: a row's mean ± standard deviation over scene seeds, and whether a change
between two variants measured on the same seeds is larger than the noise.

Every benchmark row is trained once per scene seed; each seed is a different synthetic scene (room, camera
path, label noise), so the spread over seeds is the spread a user would see between scenes. Two variants
compared on the same seeds are compared *per seed* (paired differences): the scene-to-scene spread, which
moves both variants alike, cancels.

Examples
--------
>>> [round(x, 6) for x in mean_std([0.5, 0.7, 0.6])]
[0.6, 0.1, 3]
>>> d = paired_difference({0: 0.60, 1: 0.70, 2: 0.65}, {0: 0.50, 1: 0.61, 2: 0.54})
>>> round(d["mean"], 3), d["n"], d["significant"]
(0.1, 3, True)
"""

from __future__ import annotations

import math
from typing import Any, Iterable, Mapping

#: A paired difference is significant when its mean is more than this many standard errors from 0.
SIGNIFICANCE_SE = 2.0


def _finite(values: Iterable[Any]) -> list[float]:
    out = []
    for v in values:
        try:
            f = float(v)
        except (TypeError, ValueError):
            continue
        if math.isfinite(f):
            out.append(f)
    return out


def mean_std(values: Iterable[Any]) -> tuple[float | None, float | None, int]:
    """Mean, sample standard deviation (n − 1) and count of the finite values; None where undefined
    (no value; one value has no standard deviation).

    Examples
    --------
    >>> mean_std([1.0, None, float("nan"), 3.0])
    (2.0, 1.4142135623730951, 2)
    >>> mean_std([4.0])
    (4.0, None, 1)
    """
    xs = _finite(values)
    n = len(xs)
    if not n:
        return None, None, 0
    m = sum(xs) / n
    if n < 2:
        return m, None, n
    return m, math.sqrt(sum((x - m) ** 2 for x in xs) / (n - 1)), n


def paired_difference(a: Mapping[Any, Any], b: Mapping[Any, Any]) -> dict:
    """``a − b`` over the keys (seeds) both have a finite value for.

    Returns
    -------
    dict
        ``mean``, ``std`` (sample), ``se`` (standard error ``std / √n``), ``n``, ``per_seed`` (key →
        difference) and ``significant``: ``|mean| > 2 · se`` with at least 2 pairs (the sign of the change is
        then unlikely to be noise); None for what cannot be computed.
    """
    per_seed = {}
    for k in a:
        if k in b:
            d = _finite([a[k]]), _finite([b[k]])
            if d[0] and d[1]:
                per_seed[k] = d[0][0] - d[1][0]
    m, s, n = mean_std(per_seed.values())
    se = s / math.sqrt(n) if s is not None else None
    significant = None
    if m is not None and se is not None:
        significant = abs(m) > SIGNIFICANCE_SE * se
    return {"mean": m, "std": s, "se": se, "n": n, "per_seed": per_seed, "significant": significant}


def fmt_pm(mean: float | None, std: float | None, nd: int = 3) -> str:
    """``0.812 ± 0.031`` (``–`` without a mean; no ``±`` without a spread).

    Examples
    --------
    >>> fmt_pm(0.81234, 0.0312), fmt_pm(12.0, None, 0), fmt_pm(None, None)
    ('0.812 ± 0.031', '12', '–')
    """
    if mean is None:
        return "–"
    return f"{mean:.{nd}f}" + (f" ± {std:.{nd}f}" if std is not None else "")


def fmt_diff(d: Mapping[str, Any], nd: int = 3) -> str:
    """A paired difference as ``+0.052 ± 0.011 (n=3)``: mean ± standard error.

    Examples
    --------
    >>> fmt_diff({"mean": 0.0523, "se": 0.0114, "n": 3})
    '+0.052 ± 0.011 (n=3)'
    """
    if d.get("mean") is None:
        return "–"
    se = d.get("se")
    return f"{d['mean']:+.{nd}f}" + (f" ± {se:.{nd}f}" if se is not None else "") + f" (n={d.get('n', 0)})"
