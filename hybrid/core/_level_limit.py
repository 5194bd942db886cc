"""A one-sided limit of the measured level: the recording sits flat at its extreme while the model goes on.

A hard limit of the measured output (a tank that overflows, an end stop, a
sensor at the top of its range) leaves a trace no residual regression needs
to learn: the recording stays flat at its largest (or smallest) value, to
within the noise, for a run of samples, while the simulation, which lacks the
limit, passes through that level and beyond. `level_limits` looks for exactly
that, on each side, over every part of the split it is given (a limit reached
only in the training part is still where the model fails):

- the samples within ``TOLERANCE`` noise standard deviations (or one
  quantisation step of the record, if larger) of the record's extreme, in runs of at least ``MIN_RUN`` consecutive samples of one segment;
- over those runs, the simulation's output beyond the level by more than
  ``BEYOND`` noise standard deviations somewhere, and moving over a span of
  more than ``MOVING`` of them while the recording stays flat.

A plateau the model also follows (a drive held at its largest level, a
steady state) is not a limit: there the simulation stays flat too. A smooth
peak is not either: its samples within half a noise deviation of the top come
in runs of one or two. What it cannot tell is *which* level is limited: a
flat measured output may be the measured level itself or a level upstream of
it (Cascaded Tanks: the lower tank's sensor reads its top value while the upper
tank overflows), so the sentence says where it is seen, not what causes it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

TOLERANCE = 0.5  # noise standard deviations from the extreme that count as "at" it
MIN_RUN = 5  # consecutive samples a flat run needs
BEYOND = 3.0  # the model must pass the level by this many noise standard deviations
MOVING = 3.0  # ... and span this many of them over the flat runs


def _noise_sd(w: np.ndarray, floor_variance) -> float:
    if floor_variance is not None and np.isfinite(floor_variance) and floor_variance > 0:
        return float(np.sqrt(floor_variance))
    d = np.abs(np.diff(w))  # no floor: a robust estimate from sample-to-sample differences
    return float(np.median(d) / (0.6745 * np.sqrt(2.0))) if len(d) else 0.0


def _flatness_scale(w: np.ndarray, floor_variance) -> tuple[float, float]:
    """(noise sd, quantum): what "flat" means for `w` (sd at least the quantisation step/√12)."""
    sd = _noise_sd(w, floor_variance)
    steps = np.abs(np.diff(np.unique(w)))
    # A quantised record is flat wherever it moves less than a step.
    quantum = float(steps.min()) if len(steps) else 0.0
    sd = max(sd if np.isfinite(sd) else 0.0, quantum / np.sqrt(12.0), 1e-9 * max(float(np.ptp(w)), 1e-300))
    return sd, quantum


def flat_extremes(w) -> dict[str, np.ndarray]:
    """For "top" and "bottom": the samples of `w`'s flat runs at its extreme (indices; empty if none).

    The runs `level_limits` looks at, found from the record alone (its noise
    from sample-to-sample differences): where a limit, if there is one, shows.
    """
    w = np.asarray(w, float).ravel()
    if not len(w):
        return {"top": np.zeros(0, int), "bottom": np.zeros(0, int)}
    sd, quantum = _flatness_scale(w, None)
    out = {}
    for side, sign in (("top", 1.0), ("bottom", -1.0)):
        at = sign * w >= np.max(sign * w) - max(TOLERANCE * sd, quantum)
        runs = _runs(at, np.zeros(len(w), int))
        out[side] = np.concatenate(runs) if runs else np.zeros(0, int)
    return out


def _runs(at: np.ndarray, segment: np.ndarray) -> list[np.ndarray]:
    """Index arrays of the runs of True in `at` that stay inside one segment and have MIN_RUN samples."""
    idx = np.flatnonzero(at)
    if not len(idx):
        return []
    new = np.r_[True, (np.diff(idx) != 1) | (segment[idx[1:]] != segment[idx[:-1]])]
    return [run for run in np.split(idx, np.flatnonzero(new)[1:]) if len(run) >= MIN_RUN]


def level_limits(parts: list[dict], floor_variance) -> dict:
    """For "top" and "bottom": the flat runs at the record's extreme and what the simulation does there.

    `parts`: dicts of 1-D arrays "w" (recording), "w_hat" (simulation) and
    "segment" (samples of a segment contiguous), e.g. the training and
    held-out parts of `diagnose`'s split. Returns, per side, ``level``,
    ``samples`` and ``runs`` (flat runs of ≥ MIN_RUN samples), the simulation's
    ``model_extreme`` there, ``flag`` (a limit the simulation lacks), and
    ``noise_sd`` (at least the quantisation step/√12) and ``quantum``.
    """
    parts = [{k: np.asarray(p[k], float).ravel() for k in ("w", "w_hat", "segment")} for p in parts]
    parts = [p for p in parts if len(p["w"])]
    if not parts:
        return {"reason": "no samples"}
    w_all = np.concatenate([p["w"] for p in parts])
    sd, quantum = _flatness_scale(w_all, floor_variance)
    out: dict[str, Any] = {"noise_sd": float(sd), "quantum": quantum}
    for side, sign in (("top", 1.0), ("bottom", -1.0)):
        level = float(np.max(sign * w_all))  # in sign-flipped units: the extreme is a maximum
        runs, model = [], []
        for p in parts:
            at = sign * p["w"] >= level - max(TOLERANCE * sd, quantum)
            for run in _runs(at, p["segment"]):
                runs.append(len(run))
                model.append(sign * p["w_hat"][run])
        if not runs:
            out[side] = {"level": sign * level, "samples": 0, "runs": 0, "flag": False}
            continue
        m = np.concatenate(model)
        beyond, span = float(m.max() - level), float(np.ptp(m))
        out[side] = {
            "level": sign * level,
            "samples": int(sum(runs)),
            "runs": len(runs),
            "longest_run": int(max(runs)),
            "model_extreme": float(sign * m.max()),
            "model_beyond_in_sd": beyond / sd,
            "model_span_in_sd": span / sd,
            "flag": bool(beyond > BEYOND * sd and span > MOVING * sd),
        }
    return out


def limit_sentence(limits: dict, n_samples: int, unit: str = "") -> str | None:
    """The summary's clause for each flagged side, or None when neither is flagged; levels in `unit` (w's)."""
    clauses = []
    unit = f" {unit}" if unit else ""
    for side, word, verb in (("top", "largest", "rises"), ("bottom", "smallest", "falls")):
        part = limits.get(side, {})
        if part.get("flag"):
            clauses.append(
                f"the recording sits flat at its {word} value ({part['level']:.4g}{unit}) for {part['samples']} samples "
                f"({100 * part['samples'] / max(n_samples, 1):.1f} %, {part['runs']} run"
                f"{'s' if part['runs'] > 1 else ''}) while the simulation {verb} to {part['model_extreme']:.4g}{unit} there: "
                f"a one-sided limit of the level (an overflow, an end stop, the sensor's range) that the simulation "
                f"lacks, seen in the measured output (the limited level may lie upstream of it)"
            )
    return "; ".join(clauses) if clauses else None
