"""After the stepwise search: drop a named cause that a later one made redundant.

Forward selection names the effect that explains most *given what was named
before*; a later cause can explain what an earlier one stood in for (a
hysteresis loop stood in for a baseline that wanders, until
`baseline_drift` was named beside it). So, once two or more causes are named,
each is weighed *as if it had been named last*: the final model without it
is refitted (one LM lane from the final model's end point, the cause switched
off) and the final model must clear the step's rules against that refit —
material, held-out gain ≥ `min_gain`, BIC drop ≥ `min_bic_drop`, a residual
no more correlated. A cause that fails is redundant; the weakest (least gain
over the model without it) is dropped, the refit becomes the final model, and
the check runs again while two or more causes remain. Where one cause is left
after a drop, it is weighed against the effect-free baseline, as step 1 would
have weighed it alone: the final model must clear the rules against every
model without one of its causes (a probe's cubic loss and sensor drift: a
hysteresis named at step 1 was dropped as immaterial, and the back-relaxation
named beside it, left alone, gained 1.49× over the baseline and was still
named). This is the backward
half of stepwise regression (Efroymson's forward selection with backward
elimination). A refit that lands in a worse local minimum can only keep a
cause: the check errs towards the forward search's answer. So each refit has
two more lanes, the other causes at their final values and the inner
simulation at the effect-free baseline's fit, and at the values the search
started from (the simulation as given: an `lti:N` centred on the data's time
scale). An early cause can take over what the simulation's own dynamics did
and leave them degenerate, and from the final model's end point LM does not
find them again without the cause that holds them: on a user's mass-spring
record with a sensor drift, `lti:2`'s baseline modelled the drift (f₁ 0.03 Hz,
ζ 36), `resonance` then carried the real 1.53 Hz mode, and `baseline_drift`
named beside it could not make `resonance` redundant from there.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ._decision import evaluate_candidate, materiality_of
from ._diagnosis import Candidate, EquallyGoodFits
from ._search import finite_theta, fit_lanes, lane_tangents, padding_lane
from ._step import weigh

#: No effect-free fits to set a bar: the check weighs the final model against the refit alone.
NO_BAR = EquallyGoodFits(
    n=0, heldout_nmse_min=float("nan"), heldout_nmse_max=float("nan"), definition="(not used)"
)


@dataclasses.dataclass(frozen=True)
class Dropped:
    """A named cause the final model did not need (``report.json``'s ``dropped``)."""

    name: str
    step: int
    """The step that named it (1-based)."""
    gain: float
    """Held-out NMSE of the model without it over that of the model with it."""
    reasons: tuple[str, ...]
    """The rules the model with it failed against the model without it."""
    beside: tuple[str, ...] = ()
    """The causes it was weighed beside; none: against the effect-free baseline."""

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "step": self.step,
            "gain": self.gain,
            "reasons": list(self.reasons),
            "beside": list(self.beside),
        }


def drop_redundant(search, final: Candidate, present: tuple[str, ...], baseline: Candidate | None = None):
    """(kept causes, the final model, `Dropped` entries): `present` less the causes `final` does not need.

    `search`: the `Search` every step shared; `final`: the model with every
    cause of `present` on (the last step's chosen candidate); `baseline`: the
    effect-free model, whose simulation starts one more lane of each refit.
    """
    s, settings = search, search.settings
    names = [e.name for e in s.effects]
    n_params = {e.name: len(e.constraints) for e in s.effects}
    kept, dropped = tuple(present), []
    while len(kept) >= 2:
        problem = s.problem_for(*(tuple(c for c in kept if c != cause) for cause in kept))
        assert problem.sim_tangents is not None  # a search problem always has its directions
        n_rows = int(problem.sim_tangents.shape[0])
        thetas, actives, tangents, owner = [], [], [], []
        ended = problem.model(jnp.asarray(final.theta))
        inners = [problem.model(jnp.asarray(baseline.theta)).simulation.inner] if baseline else []
        inners.append(s.model.simulation.inner)  # the baseline's fit; the given start
        for k, cause in enumerate(kept):
            active = np.asarray(final.active, float).copy()
            active[names.index(cause)] = 0.0
            lane = lane_tangents(s.model, s.frozen, tuple(c for c in kept if c != cause), n_rows)
            starts = [jnp.asarray(final.theta)]
            for inner in inners:
                again = _with_inner(problem, ended, inner, active, s.frozen)
                starts += [again] if again is not None else []
            for theta in starts:
                thetas.append(theta)
                actives.append(active)
                tangents.append(lane)
                owner.append(k)
        while len(thetas) < s.n_lanes:  # the search's lane count: its compiled program
            thetas.append(padding_lane(final.theta))
            actives.append(actives[0])
            tangents.append(tangents[0])
        s.say(f"each named cause weighed as if named last ({', '.join(kept)})")
        states = fit_lanes(
            problem,
            np.stack(actives),
            np.stack(tangents),
            jnp.stack(thetas),
            s.lm,
            settings.patience,
        )
        vals = np.asarray(states.best_val)
        weakest = None
        for k, cause in enumerate(kept):
            lanes = [j for j, o in enumerate(owner) if o == k]
            j = min(lanes, key=lambda j: vals[j] if np.isfinite(vals[j]) else np.inf)  # the better refit
            rest = tuple(c for c in kept if c != cause)
            without = evaluate_candidate(
                problem,
                states.best_theta[j],
                actives[j],
                rest[-1],
                s.n_train,
                final.n_parameters - n_params[cause],
                settings.materiality,
                s.frozen,
                rest[:-1],
            )
            with_it = dataclasses.replace(final, name=cause, reasons=[])
            with_it.material, with_it.materiality = materiality_of(
                problem, final.theta, final.active, cause, settings.materiality
            )
            weigh([with_it], without, NO_BAR, settings)
            if not with_it.eligible and (weakest is None or with_it.gain < weakest[1].gain):
                weakest = (j, with_it, without, cause)
        if weakest is None:
            break
        j, with_it, without, cause = weakest
        rest = tuple(c for c in kept if c != cause)
        dropped.append(Dropped(cause, present.index(cause) + 1, with_it.gain, tuple(with_it.reasons), rest))
        without.reasons.append(f"refitted without {cause}, which the other causes made redundant")
        without.validation_loss = float(np.asarray(states.best_val)[j])
        kept, final = rest, without
    if dropped and len(kept) == 1 and baseline is not None:  # the last one, as step 1 would weigh it alone
        (cause,) = kept
        with_it = dataclasses.replace(final, name=cause, reasons=[])
        with_it.material, with_it.materiality = materiality_of(
            s.problem, final.theta, final.active, cause, settings.materiality
        )
        weigh([with_it], baseline, NO_BAR, settings)
        if not with_it.eligible:
            dropped.append(Dropped(cause, present.index(cause) + 1, with_it.gain, tuple(with_it.reasons)))
            kept, final = (), baseline
    return kept, final, dropped


def _with_inner(problem, ended, inner, active, frozen):
    """θ of the model `ended` (the final one) with `active`'s switches and `inner` as its simulation, or None.

    The effects keep their final values; gain and offset are refitted by least
    squares (`finite_theta`). None where that model's output is not finite.
    """
    simulation = eqx.tree_at(lambda st: st.inner, ended.simulation, inner).with_active(active)
    return finite_theta(problem, simulation, ended.readout, frozen)
