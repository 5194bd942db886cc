"""Identifiability: the SVD of a sensitivity matrix names the parameter combinations the output cannot fix."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ..util._errors import InputError

#: The keys of `Identifiability.to_dict` a study's report carries (all but names and directions).
SUMMARY_KEYS = (
    "singular_values",
    "relative_singular_values",
    "null_directions",
    "near_null_directions",
    "collinear_pairs",
    "cosines",
    "tolerances",
)


@dataclasses.dataclass(frozen=True)
class Identifiability:
    """What the SVD of a (normalised) sensitivity matrix S = U Σ Vᵀ says.

    **Fields:**

    - `names`: parameter of each column of S.
    - `singular_values`: σ_1 ≥ … ≥ σ_k of S; k values even when S has fewer
      rows m than columns k (σ_{m+1} … σ_k are then 0, their directions null).
    - `directions`: (k, k), row i is the right singular vector v_i, a
      combination of parameters (log-parameter coordinates for normalised S);
      its sign is chosen so that its first coefficient of magnitude ≥ 0.1 is positive.
    - `null_directions`: combinations with σ_i ≤ `null_tolerance` · σ_1 (the
      output does not change along them at all), as {name: coefficient}.
    - `near_null_directions`: those with σ_i ≤ `near_null_tolerance` · σ_1.
    - `cosines`: (k, k) cosine between columns (±1: the two parameters change y
      in the same way, up to scale).
    - `collinear_pairs`: (name_a, name_b, cosine) with |cosine| ≥ `collinearity`
      (exactly null pairs included), most collinear first.
    - `tolerances`: the three thresholds used.
    """

    names: tuple[str, ...]
    singular_values: np.ndarray
    directions: np.ndarray
    null_directions: list[dict[str, float]]
    near_null_directions: list[dict[str, float]]
    cosines: np.ndarray
    collinear_pairs: list[tuple[str, str, float]]
    tolerances: dict[str, float]

    def summary(self) -> dict[str, Any]:
        """`to_dict` without names and directions: what a study's report carries."""
        full = self.to_dict()
        return {k: full[k] for k in SUMMARY_KEYS}

    def to_dict(self) -> dict[str, Any]:
        return {
            "names": list(self.names),
            "singular_values": [float(s) for s in self.singular_values],
            "relative_singular_values": [float(s / self.singular_values[0]) for s in self.singular_values],
            "null_directions": self.null_directions,
            "near_null_directions": self.near_null_directions,
            "directions": [dict(zip(self.names, map(float, v))) for v in self.directions],
            "collinear_pairs": [{"pair": [a, b], "cosine": c} for a, b, c in self.collinear_pairs],
            "cosines": {
                a: dict(zip(self.names, map(float, row))) for a, row in zip(self.names, self.cosines)
            },
            "tolerances": self.tolerances,
        }


def identifiability(
    matrix,
    names,
    *,
    null_tolerance: float = 1e-10,
    near_null_tolerance: float = 1e-2,
    collinearity: float = 0.99,
    keep: float = 0.01,
) -> Identifiability:
    """Name the (nearly) non-identifiable parameter combinations of a sensitivity matrix.

    **Arguments:**

    - `matrix`: (m, k) sensitivity matrix, one column per parameter, e.g.
      `Sensitivity.normalised()` (columns ∂y/∂ log θ_j) or a fit's Jacobian.
    - `names`: the k parameter names.
    - `null_tolerance`: σ_i/σ_1 at or below which a direction is called null.
      Float64 rounding puts an exact null at ~1e-15; the default leaves room.
    - `near_null_tolerance`: σ_i/σ_1 at or below which it is called near-null
      (a relative change of 1 % of the output's rms moves the parameters along
      it by ~1/σ_i: a factor e^1 for σ_i = 0.01).
    - `collinearity`: |cosine| between two columns at or above which the pair
      is flagged (Brun et al. 2001, Water Res. 35: for two parameters the
      collinearity index is 1/√(1 − |cos|), 10 at 0.99).
    - `keep`: coefficients below this magnitude are dropped from the named
      directions (they remain in `directions`).
    """
    S = np.asarray(matrix, dtype=float)
    names = tuple(names)
    if S.ndim != 2 or S.shape[1] != len(names):
        raise InputError(f"sensitivity matrix of shape {S.shape} does not match {len(names)} names")
    if not np.all(np.isfinite(S)):
        raise InputError("the sensitivity matrix has NaN or infinite entries")
    # Fewer rows than parameters: an economy SVD returns only m directions and never
    # shows the null space; the full one does, and the missing singular values are 0.
    _, sigma, Vt = np.linalg.svd(S, full_matrices=S.shape[0] < S.shape[1])
    sigma = np.concatenate([sigma, np.zeros(Vt.shape[0] - sigma.size)])
    if sigma.size == 0 or sigma[0] == 0:
        raise InputError("the output does not depend on any parameter (all sensitivities are zero)")
    Vt = np.array([_orient(v) for v in Vt])
    ratio = sigma / sigma[0]

    def named(v):
        return {n: float(c) for n, c in zip(names, v) if abs(c) >= keep}

    null = [named(v) for v, r in zip(Vt, ratio) if r <= null_tolerance]
    near = [named(v) for v, r in zip(Vt, ratio) if null_tolerance < r <= near_null_tolerance]
    norms = np.linalg.norm(S, axis=0)
    safe = np.where(norms > 0, norms, 1.0)
    cos = (S.T @ S) / np.outer(safe, safe)
    cos[norms == 0, :] = 0.0
    cos[:, norms == 0] = 0.0
    pairs = [
        (names[a], names[b], float(cos[a, b]))
        for a in range(len(names))
        for b in range(a + 1, len(names))
        if abs(cos[a, b]) >= collinearity
    ]
    pairs.sort(key=lambda p: -abs(p[2]))
    return Identifiability(
        names=names,
        singular_values=sigma,
        directions=Vt,
        null_directions=null,
        near_null_directions=near,
        cosines=cos,
        collinear_pairs=pairs,
        tolerances={
            "null": null_tolerance,
            "near_null": near_null_tolerance,
            "collinearity": collinearity,
            "keep": keep,
        },
    )


def _orient(v):
    big = np.flatnonzero(np.abs(v) >= 0.1)
    first = big[0] if big.size else int(np.argmax(np.abs(v)))
    return v if v[first] >= 0 else -v
