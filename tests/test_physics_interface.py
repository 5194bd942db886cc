"""Physics knows itself: the generic rooms learn ranges, frozen parameters and units from the simulation.

A toy first-order lag (not the RC network) declares its own ranges and a
parameter frozen by default; the start design, `fit`'s warnings, the CLI-style
freezing and `diagnose`'s settings follow it, and no generic function falls back
to the RC network.
"""

from __future__ import annotations

from typing import ClassVar

import jax.numpy as jnp
import numpy as np
import pytest
from jax import lax

import hybrid
from hybrid import AbstractSimulation, InputError, Positive, RCNetwork, Real, encode
from hybrid.core._models import make_model as make_any_model
from hybrid.core._screen import start_design
from hybrid.discovery._diagnose import diagnose as diagnose_any
from hybrid.discovery._diagnosis import DiagnoseSettings


class Lag(AbstractSimulation):
    """y' = (k u − y)/τ, exact for a held drive; `bias` is frozen by default."""

    raw: dict
    constraints: ClassVar[dict] = {"tau_s": Positive(), "k": Positive(), "bias": Real()}
    units: ClassVar[dict] = {"tau_s": "s", "k": "1", "bias": "V"}
    plausible: ClassVar[dict] = {"tau_s": (1e-3, 1e3), "k": (1e-2, 1e2), "bias": (-1.0, 1.0)}
    typical: ClassVar[dict] = {"k": (0.5, 2.0), "tau_s": (0.1, 10.0)}
    frozen_by_default: ClassVar[dict] = {"bias": "a drive offset the readout's offset already absorbs"}
    linear_in_drive: ClassVar[bool] = False

    def __init__(self, tau_s=1.0, k=1.0, bias=0.0):
        self.raw = encode({"tau_s": tau_s, "k": k, "bias": bias}, self.constraints, "Lag")

    def simulate(self, v_in, dt):
        p = self.parameters()
        a = jnp.exp(-dt / p["tau_s"])
        return lax.scan(
            lambda y, u: (a * y + (1 - a) * p["k"] * (u + p["bias"]),) * 2, 0.0, jnp.asarray(v_in)
        )[1]


def test_the_start_design_spreads_over_the_simulations_own_ranges():
    lag = Lag(tau_s=3.0, k=1.2)
    design = start_design(lag, 64, frozen=lag.frozen_by_default)
    assert design[0] == {"k": 1.2, "tau_s": 3.0}  # the simulation as given, first
    points = np.array([[d["k"], d["tau_s"]] for d in design[1:]])
    assert list(design[1]) == ["k", "tau_s"]  # the declared order; bias is frozen
    assert points[:, 0].min() >= 0.5 and points[:, 0].max() <= 2.0
    assert points[:, 1].min() >= 0.1 and points[:, 1].max() <= 10.0
    # Positive parameters are log-spaced: as many points below the geometric centre as above.
    below = np.mean(points[:, 1] < 1.0)
    assert 0.4 <= below <= 0.6
    with_bias = start_design(lag, 64)  # freed: bias falls back to its plausible range, linear
    bias = np.array([d["bias"] for d in with_bias[1:]])
    assert bias.min() >= -1.0 and bias.max() <= 1.0 and 0.4 <= np.mean(bias < 0.0) <= 0.6


def test_the_rc_networks_design_covers_the_strips_it_declares():
    network = RCNetwork(method="zoh")
    design = start_design(network, 512, frozen=network.frozen_by_default)
    assert len(design) == 512 and "xi_h" not in design[1]
    c = np.array([d["C_clamp"] for d in design[1:]])
    alpha = np.array([d["alpha_C"] for d in design[1:]])
    assert 1e-3 <= c.min() < 2e-3 and 0.5 < c.max() <= 1.0
    assert 0.1 <= alpha.min() < 0.11 and 0.89 < alpha.max() <= 0.9


def test_frozen_defaults_come_from_the_simulation():
    assert DiagnoseSettings().frozen_for(Lag()) == ("bias",)
    assert DiagnoseSettings().frozen_for(RCNetwork()) == ("xi_h",)
    assert DiagnoseSettings(frozen=()).frozen_for(RCNetwork()) == ()
    assert hybrid.extend(Lag(), "delay").frozen_by_default == Lag().frozen_by_default
    assert "ratio" in RCNetwork().frozen_by_default["xi_h"]


def test_each_fact_is_read_as_an_attribute_and_the_old_getters_warn_but_agree():
    lag, stack = Lag(), hybrid.extend(Lag(), "delay")
    assert lag.units == Lag.units and lag.plausible == Lag.plausible  # a ClassVar dict, read on the instance
    assert stack.units == {**Lag.units, "delay_s": "s"}  # a wrapper's facts include its inner's
    assert stack.plausible == Lag.plausible and stack.typical == Lag.typical
    assert set(stack.constraints) == set(stack.parameter_names())
    old = {
        "parameter_units": lag.units,
        "parameter_constraints": lag.constraints,
        "plausible_ranges": lag.plausible,
        "default_frozen": lag.frozen_by_default,
    }
    for getter, value in old.items():
        with pytest.warns(DeprecationWarning, match=getter):
            assert getattr(stack.inner, getter)() == value
    assert lag.typical_ranges() == {**Lag.typical, "bias": (-1.0, 1.0)}  # completed from plausible
    assert (RCNetwork().output_unit, RCNetwork().linear_in_drive, Lag().output_unit) == ("{drive}", True, "")


class Unstated(AbstractSimulation):
    raw: dict

    def __init__(self):
        self.raw = {}

    def simulate(self, v_in, dt):
        return v_in


def test_a_simulation_that_states_no_constraints_or_units_gets_one_clear_line():
    with pytest.raises(InputError, match="Unstated states no constraints: give it a class-level dict"):
        _ = Unstated().constraints
    with pytest.raises(InputError, match="Unstated states no units"):
        _ = Unstated().units
    assert (
        Unstated().plausible == {} and Unstated().frozen_by_default == {} and not Unstated().linear_in_drive
    )


def test_fit_warns_against_the_simulations_own_plausible_ranges():
    rate, n = 30.0, 900
    v = np.sign(np.sin(np.arange(n) / rate * 2 * np.pi * 0.2))
    true = Lag(tau_s=5000.0, k=1.0)  # outside Lag's plausible tau (1 ms to 1000 s)
    w = np.asarray(true.simulate(v, 1 / rate)) * 2.0
    rec = hybrid.Recording.from_arrays(v_in=v, w=w, rate=rate)
    result = hybrid.fit(
        make_any_model("physics", simulation=Lag(tau_s=2.0)), rec, frozen={"bias"}, progress=False
    )
    assert any("tau_s" in warning and "plausible range" in warning for warning in result.warnings)


class LateNaN(Lag):
    """Lag's output with NaN from sample 500 on: finite where the plug-in probe looks, not after."""

    def simulate(self, v_in, dt):
        y = super().simulate(v_in, dt)
        return jnp.where(jnp.arange(y.shape[0]) >= 500, jnp.nan, y)


def test_a_simulation_non_finite_at_its_start_is_named_not_fitted():
    """No step can leave a start whose prediction is NaN: fit and fit_batch say where, not 'All-NaN slice'."""
    rate, n = 30.0, 900
    v = np.sign(np.sin(np.arange(n) / rate * 2 * np.pi * 0.2))
    rec = hybrid.Recording.from_arrays(v_in=v, w=np.asarray(Lag().simulate(v, 1 / rate)), rate=rate, name="r")
    model = make_any_model("physics", simulation=LateNaN(tau_s=2.0))
    for run in (hybrid.fit, hybrid.fit_batch):
        with pytest.raises(InputError) as error:  # a PluginError, naming the class at fault
            run(model, [rec], solver=hybrid.LevenbergMarquardt(max_steps=2))
        assert error.value.plugin is LateNaN
        message = str(error.value)
        assert (
            "LateNaN returns non-finite values (NaN or inf) at 400 of 900 samples of recording 'r'" in message
        )
        assert "the first at t = 16.6667 s" in message and "tau_s=2" in message


def test_generic_functions_need_a_simulation_and_the_front_supplies_the_papers():
    with pytest.raises(InputError, match="needs a simulation"):
        make_any_model("physics")
    assert make_any_model("normal").kind == "normal"  # the Normal model has no physics
    assert isinstance(hybrid.make_model("physics").simulation, RCNetwork)
    rec = hybrid.Recording.from_arrays(
        v_in=np.sin(np.arange(600) / 7.0), w=np.cos(np.arange(600) / 7.0), rate=30.0
    )
    with pytest.raises(InputError, match="needs a simulation"):
        diagnose_any(rec)


@pytest.mark.parametrize(
    "front, generic", [(hybrid.diagnose, diagnose_any), (hybrid.make_model, make_any_model)]
)
def test_the_fronts_show_every_argument_of_the_generic_function(front, generic):
    """`help(hybrid.diagnose)` listed ``**options``: a user could not see ``effects=`` or ``settings=``."""
    import inspect

    mine, theirs = inspect.signature(front).parameters, inspect.signature(generic).parameters
    assert list(mine) == list(theirs)
    assert all(p.kind is theirs[name].kind and p.default == theirs[name].default for name, p in mine.items())
