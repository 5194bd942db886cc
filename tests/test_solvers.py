"""Solvers as objects: `fit(solver=hybrid.LevenbergMarquardt(...))`, options checked when built.

The deprecated spellings (``solver="adam"``, flat ``max_steps``/``patience``/``learning_rate``)
must give bit-identical fits to the new one, with a `DeprecationWarning` that names it.
The module runs with DeprecationWarnings as errors: the new spelling raises none.
Sizes are tiny (RC network N = 3, 480 samples, a few steps).
"""

import warnings

import helpers as h
import numpy as np
import pytest

import hybrid
from hybrid import Adam, InputError, LevenbergMarquardt, OptimistixLM, RCNetwork, fit, fit_batch, make_model

pytestmark = pytest.mark.filterwarnings("error::DeprecationWarning")


@pytest.fixture(scope="module")
def recording():
    truth = RCNetwork(xi_rho=6.0, alpha_E=0.3, alpha_C=0.4, C_clamp=0.02, n_stages=3)
    return h.planted_physics_recording(truth, 1.7, 0.3, 0.01, seed=0, periods=2)


@pytest.fixture(scope="module")
def start():
    return make_model("physics", simulation=RCNetwork(n_stages=3))


# The same fit in both spellings: (old keywords, new solver object, the warning's new spelling).
SPELLINGS = {
    "lm": (
        dict(solver="lm", max_steps=5, patience=2),
        LevenbergMarquardt(max_steps=5, patience=2),
        "pass solver=hybrid.LevenbergMarquardt(max_steps=5, patience=2)",
    ),
    "adam": (
        dict(solver="adam", max_steps=5, learning_rate=1e-2),
        Adam(max_steps=5, learning_rate=1e-2),
        "pass solver=hybrid.Adam(max_steps=5, learning_rate=0.01)",
    ),
    "optimistix, patience ignored": (
        dict(solver="optimistix", max_steps=3, patience=0),
        OptimistixLM(max_steps=3),
        "patience does nothing for OptimistixLM",
    ),
}


@pytest.mark.parametrize("name", list(SPELLINGS))
def test_old_spelling_warns_and_gives_the_identical_fit(name, start, recording):
    old, solver, new_spelling = SPELLINGS[name]
    # two starts (the second seeded) for LM, the default; one for the others, to keep the test cheap
    common = dict(starts=2 if name == "lm" else 1, seed=3, frozen={"xi_h"}, progress=False)
    new = fit(start, recording, solver=solver, **common)  # no warning: the module turns one into an error
    with pytest.warns(DeprecationWarning, match="deprecated") as caught:
        legacy = fit(start, recording, **old, **common)
    message = str(caught[0].message)
    assert new_spelling in message, message
    assert caught[0].filename == __file__  # it points at the caller's line, not at hybrid
    assert legacy.parameters == new.parameters  # bit for bit, every parameter
    assert legacy.starts == new.starts and legacy.best_start == new.best_start
    assert legacy.settings == new.settings
    assert new.settings["solver"] == solver.name and new.settings["max_steps"] == solver.max_steps


def test_fit_batch_old_keywords_warn_and_give_the_identical_fit(start, recording):
    new = fit_batch(start, [recording], solver=LevenbergMarquardt(max_steps=5, patience=3), frozen={"xi_h"})
    with pytest.warns(DeprecationWarning, match=r"LevenbergMarquardt\(max_steps=5, patience=3\)"):
        legacy = fit_batch(start, [recording], max_steps=5, patience=3, frozen={"xi_h"})
    assert [r.parameters for r in legacy] == [r.parameters for r in new]
    assert new[0].settings["patience"] == 3 and new[0].settings["batch"] is True


def test_fit_batch_refuses_another_solver_in_one_line(start, recording):
    with pytest.raises(InputError, match="fit_batch runs Levenberg-Marquardt only") as caught:
        fit_batch(start, [recording], solver=Adam())
    assert "\n" not in str(caught.value) and "hybrid.fit" in str(caught.value)


@pytest.mark.parametrize(
    "build, phrase",
    [
        (lambda: LevenbergMarquardt(max_steps=0), "max_steps must be a positive integer"),
        (lambda: LevenbergMarquardt(max_steps=2.5), "max_steps"),
        (lambda: LevenbergMarquardt(max_steps=True), "max_steps"),
        (lambda: LevenbergMarquardt(patience=-1), "patience must be an integer ≥ 0"),
        (lambda: LevenbergMarquardt(lambda0=0.0), "lambda0"),
        (lambda: LevenbergMarquardt(ftol=float("nan")), "ftol"),
        (lambda: LevenbergMarquardt(scaling="levenberg"), "'identity' or 'marquardt'"),
        (lambda: Adam(learning_rate=-1e-3), "learning_rate must be a finite positive number"),
        (lambda: Adam(max_steps=-3), "max_steps"),
        (lambda: OptimistixLM(rtol=0), "rtol"),
    ],
)
def test_bad_options_are_refused_when_the_solver_is_built(build, phrase):
    with pytest.raises(InputError) as caught:
        build()
    message = str(caught.value)
    assert phrase in message and "\n" not in message, message


def test_a_solver_that_is_not_one_is_refused_before_fitting(start, recording):
    for bad in ("bfgs", LevenbergMarquardt, 3):
        with pytest.raises(InputError, match="hybrid.LevenbergMarquardt()"):
            fit(start, recording, solver=bad, progress=False)
    with pytest.raises(InputError, match="max_steps"), warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        fit(start, recording, max_steps=0, progress=False)  # an old keyword is checked like a field


def test_solvers_are_values_with_their_options_as_fields():
    lm = LevenbergMarquardt(max_steps=200, patience=30)
    assert lm == LevenbergMarquardt(max_steps=200, patience=30) and lm != LevenbergMarquardt()
    assert lm.lm_settings().patience == 30 and lm.lm_settings().max_steps == 200
    assert lm.record() == {
        "solver": "lm",
        "max_steps": 200,
        "patience": 30,
        "ftol": 1e-10,
        "gtol": 1e-12,
        "lambda0": 1e-3,
        "scaling": "identity",
    }
    assert hybrid.SOLVERS == ("lm", "optimistix", "adam")  # the old names, kept for one release
    assert [type(hybrid.core._solvers.solver_named(n)) for n in hybrid.SOLVERS] == [
        LevenbergMarquardt,
        OptimistixLM,
        Adam,
    ]
    assert np.isclose(Adam().learning_rate, 3e-3)


def test_fit_keeps_the_simulations_frozen_by_default_unless_given_its_own(start, recording):
    """frozen=None (the default) is the simulation's frozen_by_default, as on the CLI and in diagnose;
    an explicit frozen replaces it, () frees everything."""
    solver = LevenbergMarquardt(max_steps=3)
    xi_h = float(start.simulation.parameters()["xi_h"])
    default = fit(start, recording, solver=solver, progress=False)
    assert default.settings["frozen"] == sorted(start.simulation.frozen_by_default) == ["xi_h"]
    assert default.parameters["xi_h"] == pytest.approx(xi_h, rel=1e-12)
    free = fit(start, recording, solver=solver, frozen=(), progress=False)
    assert free.settings["frozen"] == [] and free.parameters["xi_h"] != pytest.approx(xi_h, rel=1e-6)
    batch = fit_batch(start, [recording], solver=solver)
    assert batch.results[0].settings["frozen"] == ["xi_h"]
