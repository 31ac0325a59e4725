"""Picking one plan from a Pareto front: the documented MCDM rules of RobotFleet.spec.scheduler.

- ``lexicographic``: objectives in the order of ``settings.objectives``; a plan survives a
  level if it is within ``tol = 1e-6 + 1e-3 * |best|`` of the best value left at that level
  (values closer than that are ties); the next objective breaks the ties.
- ``weighted``: min-max normalise each objective over the front (a constant objective counts
  0), then minimise pymoo's augmented scalarisation max_k w_k * f_k (+ a 1e-6 weighted sum
  against ties) with ``settings.weights`` (objectives not listed weigh 1, 0 leaves one out).
- ``knee``: in the min-max normalised space, the plan farthest below the hyperplane through
  the front's extreme points (Das 1999); where those points do not span a hyperplane, the
  plan closest (Euclidean) to the ideal point.

Every rule breaks remaining ties by the lowest index, so the choice is deterministic.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray
from pymoo.decomposition.asf import ASF
from pymoo.util.nds.non_dominated_sorting import NonDominatedSorting

__all__ = ["choose", "dominance", "non_dominated"]

F64 = NDArray[np.float64]
_CELLS = 1 << 20  # comparisons per block of ``dominance``


def _fmt(v: float) -> str:
    return f"{v:.4g}"


def dominance(F: F64, A: F64, *, strict: bool = True) -> NDArray[np.bool_]:
    """Rows of F that some row of A dominates (minimisation: <= everywhere and < somewhere);
    with ``strict=False`` also rows equal to a row of A (weak dominance). Blocked over F
    and looped over objectives, so memory stays at (block, len(A))."""
    F = np.asarray(F, dtype=np.float64)
    A = np.asarray(A, dtype=np.float64)
    out = np.zeros(len(F), dtype=bool)
    if len(F) == 0 or len(A) == 0:
        return out
    block = max(1, _CELLS // len(A))
    for s in range(0, len(F), block):
        f = F[s : s + block]
        le = np.ones((len(f), len(A)), dtype=bool)
        lt = np.zeros((len(f), len(A)), dtype=bool) if strict else None
        for k in range(F.shape[1]):
            a, b = A[None, :, k], f[:, None, k]
            le &= a <= b
            if lt is not None:
                lt |= a < b
        out[s : s + block] = (le & lt if lt is not None else le).any(axis=1)
    return out


def non_dominated(F: F64) -> NDArray[np.int64]:
    """Indices (ascending) of the rows of F (minimisation) that no other row dominates;
    duplicates of a kept row are dropped (first kept)."""
    F = np.asarray(F, dtype=np.float64)
    if len(F) == 0:
        return np.zeros(0, dtype=np.int64)
    first = np.sort(np.unique(F, axis=0, return_index=True)[1])
    # pymoo's compiled non-dominated sorting (first front only): ~25x faster than a pairwise
    # dominance matrix on fronts of thousands of plans
    front = NonDominatedSorting().do(F[first], only_non_dominated_front=True)
    return np.sort(first[np.asarray(front, dtype=np.int64)]).astype(np.int64)


def _normalise(F: F64) -> F64:
    lo, hi = F.min(axis=0), F.max(axis=0)
    span = np.where(hi - lo > 0, hi - lo, 1.0)
    return np.asarray((F - lo) / span, dtype=np.float64)


def _lexicographic(F: F64, names: Sequence[str]) -> tuple[int, str]:
    """The plan the levels leave and a reason quoting *its* values (a plan within a level's
    tolerance of the best is not the best: the reason says both where they differ)."""
    cand = np.arange(len(F))
    levels: list[tuple[int, float, float, int]] = []  # objective, best, tolerance, within
    for k in range(len(names)):
        col = F[cand, k]
        best = float(col.min())
        tol = 1e-6 + 1e-3 * abs(best)
        within = cand[col <= best + tol]
        if k == 0 or len(cand) > 1:
            levels.append((k, best, tol, len(within)))
        cand = within
        if len(cand) == 1:
            break
    idx = int(cand[np.argmin(F[cand, 0])])
    notes: list[str] = []
    for k, best, tol, n_within in levels:
        value = float(F[idx, k])
        same = _fmt(value) == _fmt(best)
        if k == 0:
            if same:
                text = f"lowest {names[0]} {_fmt(value)} among {len(F)} non-dominated plans"
            else:
                text = (
                    f"{names[0]} {_fmt(value)}, within {_fmt(tol)} of the lowest "
                    f"{_fmt(best)} among {len(F)} non-dominated plans"
                )
            if n_within > 1:
                text += f" ({n_within} within {_fmt(tol)} of it)"
            notes.append(text)
        else:
            notes.append(f"{names[k]} {_fmt(value)}" + ("" if same else f" (lowest {_fmt(best)})"))
    reason = notes[0]
    if len(notes) > 1:
        reason += "; ties broken by " + ", then ".join(notes[1:])
    return idx, reason


def _weighted(F: F64, names: Sequence[str], weights: Mapping[str, float]) -> tuple[int, str]:
    """pymoo's augmented scalarisation (ASF) on the min-max normalised front: the plan whose
    worst weighted objective is smallest. Unlike a weighted sum it can pick plans in concave
    parts of the front; a weight of 0 leaves an objective out."""
    w = np.array([float(weights.get(n, 1.0)) for n in names])
    used = w > 0
    Z = _normalise(F)[:, used]
    score = ASF().do(Z, 1.0 / w[used]).reshape(-1) + 1e-6 * (Z @ w[used])  # augmented: ties
    idx = int(np.argmin(score))
    parts = ", ".join(f"{_fmt(wk)}*{n}" for wk, n in zip(w, names, strict=True))
    return idx, (
        f"lowest weighted worst objective {_fmt(float(score[idx]))} (ASF) of min-max normalised "
        f"objectives ({parts}) among {len(F)} non-dominated plans"
    )


def _knee(F: F64, names: Sequence[str]) -> tuple[int, str]:
    Z = _normalise(F)
    m = Z.shape[1]
    ext = np.array([int(np.argmin(F[:, k])) for k in range(m)])
    if m >= 2 and len(set(ext.tolist())) == m:
        E = Z[ext]
        try:
            normal = np.linalg.solve(E, np.ones(m))  # hyperplane normal . z = 1
        except np.linalg.LinAlgError:
            normal = None
        if normal is not None and np.all(np.isfinite(normal)):
            dist = (1.0 - Z @ normal) / np.linalg.norm(normal)
            idx = int(np.argmax(dist))
            return idx, (
                f"knee point: farthest ({_fmt(float(dist[idx]))}) below the hyperplane through the "
                f"extreme plans of {', '.join(names)} among {len(F)} non-dominated plans"
            )
    d = np.linalg.norm(Z, axis=1)
    idx = int(np.argmin(d))
    return idx, (
        f"closest to the ideal point (normalised distance {_fmt(float(d[idx]))}) among {len(F)} "
        "non-dominated plans"
    )


def choose(
    F: F64,
    names: Sequence[str],
    rule: str = "lexicographic",
    weights: Mapping[str, float] | None = None,
) -> tuple[int, str]:
    """Index of the chosen row of the front F (K, len(names)) and a sentence saying why."""
    F = np.asarray(F, dtype=np.float64)
    if F.ndim != 2 or len(F) == 0 or F.shape[1] != len(names):
        raise ValueError("choose: F must be (K >= 1, len(names))")
    if len(F) == 1:
        return 0, "the only non-dominated plan"
    if rule == "lexicographic":
        return _lexicographic(F, names)
    if rule == "weighted":
        return _weighted(F, names, weights or {})
    if rule == "knee":
        return _knee(F, names)
    raise ValueError(f"unknown choice rule {rule!r}")
