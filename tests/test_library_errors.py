"""Issue 20: the library answers a wrong argument with one InputError, never a raw error or garbage.

Wrong types at the public entry points used to raise raw TypeError/AttributeError
from deep inside (or, for `RCNetwork.simulate` with dt ≤ 0 or NaN, return
numbers without complaint). Each call below must raise `hybrid.InputError`;
the value checks must not get in the way of `jit`, `vmap` and `grad`.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hybrid
from hybrid import InputError, RCNetwork, Recording


@pytest.fixture(scope="module")
def recording():
    n = 200
    return Recording.from_arrays(
        v_in=np.sin(np.arange(n) / 5.0), w=np.cos(np.arange(n) / 4.0), rate=30.0, name="tiny"
    )


@pytest.fixture(scope="module")
def model():
    return hybrid.make_model("physics")


def _never_called(*args, **kwargs):
    raise AssertionError("the argument check should have refused before any work")


# Each case: a call and a phrase its one-line message must contain.
CASES = {
    # fit
    "fit(model as str)": (lambda m, r: hybrid.fit("physics", r), "hybrid.Model"),
    "fit(model None)": (lambda m, r: hybrid.fit(None, r), "hybrid.Model"),
    "fit(recordings int)": (lambda m, r: hybrid.fit(m, 5), "Recording objects"),
    "fit(recordings dict)": (lambda m, r: hybrid.fit(m, {"t": [0, 1]}), "Recording objects"),
    "fit(frozen int)": (lambda m, r: hybrid.fit(m, r, frozen=3), "frozen"),
    "fit(frozen unknown)": (lambda m, r: hybrid.fit(m, r, frozen={"bogus"}), "valid names"),
    "fit(seed str)": (lambda m, r: hybrid.fit(m, r, seed="a"), "seed"),
    "fit_batch(model str)": (lambda m, r: hybrid.fit_batch("physics", [r]), "hybrid.Model"),
    "fit_batch(recordings int)": (lambda m, r: hybrid.fit_batch(m, 7), "Recording objects"),
    # diagnose
    "diagnose(int)": (lambda m, r: hybrid.diagnose(5), "Recording objects"),
    "diagnose(settings dict)": (
        lambda m, r: hybrid.diagnose(r, settings={"max_steps": 1}),
        "DiagnoseSettings",
    ),
    "diagnose(simulation int)": (lambda m, r: hybrid.diagnose(r, simulation=3), "needs a simulation"),
    "diagnose(simulation spec unknown)": (
        lambda m, r: hybrid.diagnose(r, simulation="rcx"),
        "--physics rcx: not a physics I know",
    ),
    "write_report(str)": (lambda m, r: hybrid.write_report("x", "out"), "Diagnosis"),
    # simulate
    "simulate(dt < 0)": (lambda m, r: RCNetwork().simulate(jnp.ones(8), -0.1), "dt"),
    "simulate(dt = 0)": (lambda m, r: RCNetwork().simulate(jnp.ones(8), 0.0), "dt"),
    "simulate(dt NaN)": (lambda m, r: RCNetwork().simulate(jnp.ones(8), float("nan")), "dt"),
    "simulate(dt str)": (lambda m, r: RCNetwork().simulate(jnp.ones(8), "0.1"), "dt"),
    "simulate(dt array)": (lambda m, r: RCNetwork().simulate(jnp.ones(8), np.ones(3)), "dt"),
    "simulate(NaN in v)": (lambda m, r: RCNetwork().simulate(jnp.array([1.0, np.nan, 1.0]), 0.1), "sample 1"),
    "simulate(inf in v, zoh)": (
        lambda m, r: RCNetwork(method="zoh").simulate(np.array([np.inf, 0.0]), 0.1),
        "sample 0",
    ),
    "simulate(v str)": (lambda m, r: RCNetwork().simulate("abc", 0.1), "v_in"),
    "simulate(v 2-D)": (lambda m, r: RCNetwork().simulate(jnp.ones((3, 8)), 0.1), "shape"),
    "predict(dt str)": (lambda m, r: m.predict(jnp.ones(8), "a"), "dt"),
    "normal model predict(NaN)": (
        lambda m, r: hybrid.Passthrough().simulate(np.array([np.nan]), 0.1),
        "v_in",
    ),
    "simulate_batch(str)": (lambda m, r: hybrid.simulate_batch("rc", jnp.ones(8), 0.1), "simulations"),
    "simulate_batch([str])": (lambda m, r: hybrid.simulate_batch(["rc"], jnp.ones(8), 0.1), "simulations"),
    "simulate_batch(dt < 0)": (lambda m, r: hybrid.simulate_batch([RCNetwork()], jnp.ones(8), -1.0), "dt"),
    # models on disk
    "load_model(int)": (lambda m, r: hybrid.load_model(5), "file path"),
    "load_model(None)": (lambda m, r: hybrid.load_model(None), "file path"),
    "save_model(model str)": (lambda m, r: hybrid.save_model("x.eqx", "model"), "hybrid.Model"),
    "save_model(path int)": (lambda m, r: hybrid.save_model(5, m), "file path"),
    "save_model(extra not JSON)": (lambda m, r: hybrid.save_model("y.eqx", m, extra={"a": object()}), "JSON"),
    # recordings
    "Recording.load(int)": (lambda m, r: Recording.load(5), "file path"),
    "Recording.load(None)": (lambda m, r: Recording.load(None), "file path"),
    "Recording.save(int)": (lambda m, r: r.save(5), "file path"),
    # constructors
    "RCNetwork(str)": (lambda m, r: RCNetwork("a"), "xi_rho must be a number"),
    "RCNetwork(None)": (lambda m, r: RCNetwork(None), "xi_rho must be a number"),
    "RCNetwork(C_clamp=object)": (lambda m, r: RCNetwork(C_clamp=object()), "C_clamp must be a number"),
    "RCNetwork(strip str)": (lambda m, r: RCNetwork(strip="x"), "hybrid.Strip"),
    "make_model(simulation list)": (
        lambda m, r: hybrid.make_model("hybrid", simulation=["rc"]),
        "or a --physics spec such as 'lti:2'",
    ),
    "make_model(simulation spec bad)": (
        lambda m, r: hybrid.make_model("hybrid", simulation="lti:x"),
        "the order N of lti:N must be a whole number",
    ),
    "make_model(key int)": (lambda m, r: hybrid.make_model("hybrid", key=3), "PRNG key"),
    "make_model(kind list)": (lambda m, r: hybrid.make_model(["hybrid"]), "model must be one of"),
}


@pytest.mark.parametrize("name", list(CASES))
def test_wrong_arguments_raise_one_input_error(name, model, recording, tmp_path, monkeypatch):
    import hybrid.core._levenberg_marquardt

    monkeypatch.chdir(tmp_path)
    # Nothing may start fitting: each refusal comes from the argument checks.
    monkeypatch.setattr(hybrid.core._fit, "lm_run", _never_called)
    monkeypatch.setattr(hybrid.core._levenberg_marquardt, "lm_run", _never_called)
    call, phrase = CASES[name]
    with pytest.raises(InputError) as caught:
        call(model, recording)
    message = str(caught.value)
    assert phrase in message and "\n" not in message, message
    assert list(tmp_path.iterdir()) == []  # and nothing was written


def test_a_physics_spec_string_is_resolved_as_the_command_line_resolves_it(recording, monkeypatch):
    """``simulation="lti:2"`` is ``--physics lti:2``: `resolve_physics` with the recordings (its start)."""
    import hybrid.discovery._diagnose

    seen = {}

    def stop(recordings, simulation, *args, **kwargs):
        seen["simulation"] = simulation
        raise InputError("stopped after the argument checks")

    monkeypatch.setattr(hybrid.discovery._diagnose, "prepare_search", stop)
    with pytest.raises(InputError, match="stopped"):
        hybrid.diagnose(recording, simulation="lti:2")
    values = lambda simulation: {k: float(v) for k, v in simulation.parameters().items()}
    expected = hybrid.resolve_physics("lti:2", recording)
    assert type(seen["simulation"]) is type(expected)
    assert values(seen["simulation"]) == pytest.approx(values(expected))
    assert values(hybrid.resolve_physics("lti:2")) != pytest.approx(values(expected))  # started on the data
    assert isinstance(hybrid.make_model("physics", simulation="lti:3").simulation, hybrid.LTI)


def test_fit_reads_a_single_frozen_name_as_one_name(model, recording, monkeypatch):
    # "xi_h" used to be read as {"x", "i", "_", "h"}.
    import hybrid.core._fit

    seen = {}
    as_names = hybrid.core._fit.as_names

    def spy(*args, **kwargs):
        seen["frozen"] = as_names(*args, **kwargs)
        return seen["frozen"]

    def stop(*args, **kwargs):
        raise InputError("stopped after the argument checks")

    monkeypatch.setattr(hybrid.core._fit, "as_names", spy)
    monkeypatch.setattr(hybrid.core._fit, "series_from_recording", stop)
    with pytest.raises(InputError, match="stopped"):
        hybrid.fit(
            model, recording, frozen="xi_h", solver=hybrid.LevenbergMarquardt(max_steps=1), progress=False
        )
    assert seen["frozen"] == frozenset({"xi_h"})


def test_fit_accepts_a_recording_path(model, recording, tmp_path, monkeypatch):
    path = recording.save(tmp_path / "tiny.csv")
    seen = {}

    import hybrid.core._fit

    def stop(r, *args):
        seen["recording"] = r
        raise InputError("stopped after loading")

    monkeypatch.setattr(hybrid.core._fit, "series_from_recording", stop)
    with pytest.raises(InputError, match="stopped after loading"):
        hybrid.fit(model, str(path), solver=hybrid.LevenbergMarquardt(max_steps=1), progress=False)
    assert seen["recording"] == recording


def test_simulate_checks_do_not_get_in_the_way_of_jit_vmap_grad():
    net = RCNetwork(n_stages=1)
    v = jnp.sin(jnp.arange(16) / 4.0)
    simulate = jax.jit(lambda v, dt: net.simulate(v, dt))  # v and dt are tracers inside
    direct = simulate(v, 0.1)
    both = jax.jit(jax.vmap(simulate, in_axes=(0, None)))(jnp.stack([v, 2 * v]), 0.1)
    np.testing.assert_allclose(both[1], 2 * direct, rtol=1e-12)
    grad = jax.jit(jax.grad(lambda dt: simulate(v, dt).sum()))(0.1)
    assert np.all(np.isfinite(direct)) and np.isfinite(grad)
