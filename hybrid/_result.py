"""The typed result of a fit."""

from __future__ import annotations

import dataclasses
from typing import Any

from ._models import Model


@dataclasses.dataclass(frozen=True)
class FitResult:
    """What [`hybrid.fit`][] returns.

    **Fields:**

    - `model`: the fitted model (best start, best iterate by validation loss).
    - `parameters`: fitted interpretable parameters by name, physical units.
    - `units`: unit of each parameter.
    - `metrics`: per split (``"train"``, ``"validation"``, ``"test"``), a dict of
      ``nmse`` (Eq 18, each signal by its own max |·|), ``nmse_target`` (both by
      max |w|), ``nmse_variance`` (MSE / var w) and ``fitting`` (Eq 20, %).
    - `history`: one dict per progress report: step, train cost and validation
      loss of each start.
    - `starts`: per start: best validation loss, steps, accepted steps, best step.
    - `best_start`: index of the start that was kept.
    - `settings`: solver, starts, frozen parameters, split, seed, … (JSON-able).
    - `seconds`: wall time of the fit, compile time included.
    """

    model: Model
    parameters: dict[str, float]
    units: dict[str, str]
    metrics: dict[str, dict[str, float]]
    history: list[dict[str, Any]]
    starts: list[dict[str, Any]]
    best_start: int
    settings: dict[str, Any]
    seconds: float

    def summary(self) -> str:
        """A few readable lines: metrics per split and the fitted parameters."""
        lines = [f"{self.model.kind} model, {self.settings.get('solver')} "
                 f"({len(self.starts)} start(s), kept #{self.best_start}), {self.seconds:.1f} s"]
        for split, m in self.metrics.items():
            lines.append(
                f"  {split:<10} NMSE {m['nmse']:.3e}  NMSE(target) {m['nmse_target']:.3e}  "
                f"Fitting {m['fitting']:6.2f} %"
            )
        for name, value in self.parameters.items():
            lines.append(f"  {name:<8} = {value:.6g} {self.units.get(name, '')}".rstrip())
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able record of the fit (without the weights)."""
        return {
            "kind": self.model.kind,
            "parameters": self.parameters,
            "units": self.units,
            "metrics": self.metrics,
            "starts": self.starts,
            "best_start": self.best_start,
            "settings": self.settings,
            "seconds": self.seconds,
            "history": self.history,
        }
