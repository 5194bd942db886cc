"""Any physics plugs in: the generic LTI(N), `resolve_physics`, and a plug-in fitted from a file.

References are independent of the library: scipy.signal's ZOH discretisation and
`dlsim` for LTI, scipy's `solve_ivp` for the ODE plug-ins.
"""

from __future__ import annotations

import sys
import textwrap
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.signal
from helpers import LEAPFROG, run_hybrid
from scipy.integrate import solve_ivp

import hybrid
from hybrid import LTI, InputError, RCNetwork, resolve_physics

ROOT = Path(__file__).resolve().parents[1]
DT = 1 / 30


def _with_raw(sim, raw):
    return eqx.tree_at(lambda s: s.raw, sim, raw)


def _random(order, seed, scale=0.5):
    """LTI(order) with its default raw values moved by N(0, scale²)."""
    rng = np.random.default_rng(seed)
    sim = LTI(order)
    return _with_raw(sim, {k: v + scale * rng.standard_normal() for k, v in sim.raw.items()})


# --- LTI ---------------------------------------------------------------------------------


@pytest.mark.parametrize("order", [1, 2, 3, 4])
def test_lti_matches_scipys_zoh_discretisation(order):
    sim = _random(order, seed=order)
    A, B, C, D = (np.asarray(x) for x in sim.state_space())
    u = np.random.default_rng(10 + order).standard_normal(700)
    ad, bd, cd, dd, _ = scipy.signal.cont2discrete(
        (A, B[:, None], C[None, :], np.array([[float(D)]])), DT, "zoh"
    )
    _, expected, _ = scipy.signal.dlsim((ad, bd, cd, dd, DT), u)
    expected = expected[:, 0]
    got = np.asarray(eqx.filter_jit(lambda s, v: s.simulate(v, DT))(sim, jnp.asarray(u)))
    assert np.max(np.abs(got - expected)) <= 1e-9 * np.max(np.abs(expected))
    # the transfer function scipy sees has the declared order and the parameters' poles
    assert A.shape == (order, order) and len(sim.parameters()) == 2 * order


def test_lti_is_stable_for_any_raw_values():
    sim = LTI(5)
    keys = jax.random.split(jax.random.key(3), 64)
    raws = jax.vmap(lambda k: sim.perturbed(k, 3.0).raw)(keys)  # wild: e^±9 time scales
    ad = jax.jit(jax.vmap(lambda raw: _with_raw(sim, raw).discrete(DT)[0]))(raws)
    radius = np.max(np.abs(np.linalg.eigvals(np.asarray(ad))), axis=1)
    assert np.all(radius < 1.0)
    # and the same under vmap over systems for a drive: finite and bounded
    u = jnp.asarray(np.sign(np.sin(np.arange(300) / 9.0)))
    y = jax.jit(jax.vmap(lambda raw: _with_raw(sim, raw).simulate(u, DT)))(
        jax.tree.map(lambda x: x[:8], raws)
    )
    assert np.all(np.isfinite(np.asarray(y)))


def test_lti_gradient_matches_central_differences():
    sim = _random(3, seed=7, scale=0.3)
    u = jnp.asarray(np.random.default_rng(1).standard_normal(200))
    w = jnp.asarray(np.random.default_rng(2).standard_normal(200))

    @jax.jit
    def loss(raw):
        return jnp.sum(w * _with_raw(sim, raw).simulate(u, DT))

    grad = jax.grad(loss)(sim.raw)
    for name in ("tau_1", "f_2", "zeta_2", "bandpass_2"):
        h = 1e-6
        up = loss({**sim.raw, name: sim.raw[name] + h})
        down = loss({**sim.raw, name: sim.raw[name] - h})
        assert float(grad[name]) == pytest.approx(float(up - down) / (2 * h), rel=1e-6, abs=1e-9)


def test_lti_parameters_are_its_own_and_survive_save_and_load(tmp_path):
    sim = LTI(3, tau_1=0.2, f_2=4.0, zeta_2=1.5, lowpass_2=-0.5)
    assert sim.parameter_names() == ("tau_1", "f_2", "zeta_2", "lowpass_2", "bandpass_2", "direct")
    for fact in (sim.constraints, sim.units, sim.plausible, sim.typical, sim.typical_ranges()):
        assert list(fact) == list(sim.parameter_names())  # its order's parameters, in its order
    assert sim.units["f_2"] == "Hz" and sim.linear_in_drive and LTI(1).units == {"tau_1": "s", "direct": "1"}
    assert float(sim.replace(zeta_2=0.3).parameters()["zeta_2"]) == pytest.approx(0.3)
    with pytest.raises(InputError, match="lowpass_1"):
        LTI(2, lowpass_1=2.0)  # fixed at 1: the readout's gain carries the scale
    with pytest.raises(InputError, match="from 1 to 20"):
        LTI(21)
    model = hybrid.Model(sim, hybrid.LinearReadout(gain=2.0, offset=0.1), "physics")
    loaded = hybrid.load_model(hybrid.save_model(tmp_path / "lti.eqx", model))
    assert isinstance(loaded.simulation, LTI) and loaded.simulation.order == 3
    assert {k: float(v) for k, v in loaded.parameters().items()} == {
        k: float(v) for k, v in model.parameters().items()
    }


# --- resolve_physics -------------------------------------------------------------------------

PLUGIN = '''
"""A first-order lag behind a square-root valve: tau y' = sqrt(u + bias) - y, the drive held per sample."""
from typing import ClassVar

import jax.numpy as jnp
from jax import lax

from hybrid import AbstractSimulation, Positive
from hybrid import encode


class SqrtLag(AbstractSimulation):
    raw: dict
    constraints: ClassVar[dict] = {"tau": Positive(), "bias": Positive()}
    units: ClassVar[dict] = {"tau": "s", "bias": "V"}
    plausible: ClassVar[dict] = {"tau": (1e-3, 1e3), "bias": (1e-3, 1e2)}

    def __init__(self, tau=1.0, bias=1.0):
        self.raw = encode({"tau": tau, "bias": bias}, self.constraints, "SqrtLag")

    def simulate(self, v_in, dt):
        p = self.parameters()
        target = jnp.sqrt(jnp.maximum(jnp.asarray(v_in) + p["bias"], 1e-9))
        a = jnp.exp(-dt / p["tau"])
        return lax.scan(lambda y, s: (s + (y - s) * a, y), target[0], target)[1]  # from equilibrium


class Helper:
    pass


class Broken(SqrtLag):
    def __init__(self):
        raise RuntimeError("the valve table is missing")
'''


@pytest.fixture
def plugin_file(tmp_path):
    path = tmp_path / "valve.py"
    path.write_text(textwrap.dedent(PLUGIN))
    return path


def test_resolve_the_builtin_physics():
    assert isinstance(resolve_physics("rc"), RCNetwork)
    lti = resolve_physics(" lti:3 ")
    assert isinstance(lti, LTI) and lti.order == 3
    assert isinstance(resolve_physics("hybrid.physics._rc_network:RCNetwork"), RCNetwork)


def test_resolve_a_class_from_a_file_and_from_a_module(plugin_file, monkeypatch):
    sim = resolve_physics(f"{plugin_file}:SqrtLag")
    assert type(sim).__name__ == "SqrtLag" and sim.parameter_names() == ("tau", "bias")
    module = type(sim).__module__
    assert module.startswith("hybrid_plugin_valve_") and sys.modules[module].SqrtLag is type(sim)
    assert type(resolve_physics(f"{plugin_file}:SqrtLag")) is type(sim)  # the same file, the same class
    monkeypatch.syspath_prepend(str(plugin_file.parent))
    monkeypatch.delitem(sys.modules, "valve", raising=False)
    try:
        assert type(resolve_physics("valve:SqrtLag")).__module__ == "valve"
    finally:
        sys.modules.pop("valve", None)


def test_a_plugin_without_recordings_is_probed_at_the_rate_it_will_run_at(tmp_path):
    (tmp_path / "leapfrog.py").write_text(LEAPFROG)
    spec = f"{tmp_path / 'leapfrog.py'}:Leapfrog"
    assert type(resolve_physics(spec, rate=50.0)).__name__ == "Leapfrog"  # stable at 50 Hz: accepted
    message = _one_error(spec, "non-finite", "step from 0 to 1 V at 30 Hz")  # no rate: a camera's 30 Hz
    assert "Leapfrog.simulate" in message


def _one_error(spec, *words):
    with pytest.raises(InputError) as caught:
        resolve_physics(spec)
    message = str(caught.value)
    error = caught.value
    assert error.__cause__ is None and (
        error.__context__ is None or error.__suppress_context__
    )  # one, no chain
    assert message.startswith(f"--physics {spec}")
    for word in words:
        assert word in message, message
    return message


def test_every_failure_is_one_input_error_that_names_the_fix(plugin_file, tmp_path):
    _one_error("lti:0", "from 1 to 20", "lti:2")
    _one_error("lti:two", "whole number")
    _one_error("spring", "rc, rc:zoh, lti:N", "file.py:ClassName")
    _one_error(f"{tmp_path / 'missing.py'}:SqrtLag", "no file", "check the path")
    bad = tmp_path / "bad.py"
    bad.write_text("class Oops(:\n    pass\n")
    _one_error(f"{bad}:Oops", "syntax error at line 1", "fix the file")
    failing = tmp_path / "failing.py"
    failing.write_text("import no_such_package_here\n")
    _one_error(f"{failing}:X", "ModuleNotFoundError", "no_such_package_here")
    _one_error(f"{plugin_file}:TwoTank", "valve.py has no class TwoTank", "it defines: Broken, SqrtLag")
    _one_error(f"{plugin_file}:Helper", "not an AbstractSimulation subclass", "hybrid.AbstractSimulation")
    _one_error(f"{plugin_file}:encode", "a function, not a class")
    _one_error(f"{plugin_file}:Broken", "Broken() raised RuntimeError", "valve table", "no arguments")
    _one_error(f"{plugin_file}:", "not a Python class name")
    _one_error("hybrid.physics._lti:LTI", "LTI() raised TypeError", "no arguments")
    _one_error("no_such_module_xyz:Thing", "no module named no_such_module_xyz", "PYTHONPATH")
    _one_error("hybrid.core._simulation:AbstractSimulation", "abstract", "simulate")
    assert not [m for m in sys.modules if m.startswith(("hybrid_plugin_bad_", "hybrid_plugin_failing_"))]


HEATER = """
from typing import ClassVar

import jax.numpy as jnp

from hybrid import AbstractStateSpace, Positive, encode


class Heater(AbstractStateSpace):
    raw: dict
    constraints: ClassVar = {"capacity": Positive(), "resistance": Positive()}
    units: ClassVar = {"capacity": "J/K", "resistance": "K/W"}
    typical: ClassVar = {"capacity": (1.0, 100.0)}
    plausible: ClassVar = {"capacity": (0.01, 1e5), "resistance": (1e-3, 1e3)}
    frozen_by_default: ClassVar = {"resistance": "only tau = R C is seen"}
    states: ClassVar = ("rise",)

    def __init__(self, capacity=10.0, resistance=2.0):
        self.raw = encode(dict(capacity=capacity, resistance=resistance), self.constraints, "Heater")

    def rates(self, x, u, p):
        return ((u - x[0] / p["resistance"]) / p["capacity"],)

    def linear_matrices(self, p):
        return jnp.array([[-1.0 / (p["resistance"] * p["capacity"])]]), jnp.array([1.0 / p["capacity"]])
"""


@pytest.mark.parametrize(
    "old, new, words",
    [
        (
            'typical: ClassVar = {"capacity"',
            'typical: ClassVar = {"capacty"',
            ["Heater.typical", "capacty", "misspelling"],
        ),
        ('(0.01, 1e5), "resistance"', '(0.01, 1e5), "resistence"', ["Heater.plausible", "resistence"]),
        ('{"resistance": "only', '{"resistence": "only', ["Heater.frozen_by_default", "resistence"]),
        ("(1.0, 100.0)", "(100.0, 1.0)", ["Heater.typical['capacity']", "low < high"]),
        (  # the drive levels its numbers hold for (`drive_range`): a range, or None
            'states: ClassVar = ("rise",)',
            'states: ClassVar = ("rise",)\n    drive_range: ClassVar = (5.0, "ten")',
            ["Heater.drive_range must be None or (low, high)", "'ten'"],
        ),
        ('states: ClassVar = ("rise",)', "", ["Heater.states", "non-empty tuple"]),
        ('p["resistance"]) / p', 'p["resistence"]) / p', ["Heater.rates raised KeyError", "resistence"]),
        ("return ((u - x[0]", "return ((2 * u - x[0]", ["rates and linear_matrices disagree", "A x + B u"]),
        (  # a new user's: the message said "checking rates against linear_matrices", before either ran
            'return ((u - x[0] / p["resistance"]) / p["capacity"],)',
            'raise RuntimeError("calibration table not loaded")',
            ["Heater.rates raised RuntimeError", "calling prepare, initial_state and rates"],
        ),
        (
            'return ((u - x[0] / p["resistance"]) / p["capacity"],)',
            "return u",
            ["rates must return a tuple of 1"],
        ),
    ],
)
def test_a_state_space_plugin_that_contradicts_itself_is_refused_on_load(tmp_path, old, new, words):
    """What only one command would read (a range, the rates beside the matrices) is checked for every command.

    A heater plug-in tried as a new user would: a misspelt key of `typical` or `plausible` was ignored
    (its parameter silently left out of the start design), one of `frozen_by_default` was refused as an
    "unknown frozen name" of a --freeze never given, a typo in `rates` went unseen by `fit` (the matrices
    step the simulation) and `states` was checked by `diagnose` alone.
    """
    source = HEATER.replace(old, new)
    assert source != HEATER
    (tmp_path / "heater.py").write_text(source)
    _one_error(f"{tmp_path / 'heater.py'}:Heater", *words)


def test_the_heater_plugin_as_written_loads(tmp_path):
    (tmp_path / "heater.py").write_text(HEATER)
    assert resolve_physics(f"{tmp_path / 'heater.py'}:Heater").parameter_names() == ("capacity", "resistance")


# --- a plug-in from a file, fitted, saved and loaded -------------------------------------------

TRUE = {"tau": 2.5, "bias": 0.4}
GAIN, OFFSET = 3.0, -0.2


def _valve_recording():
    """SqrtLag's data by scipy's solve_ivp, the drive held over each sample (no hybrid code)."""
    rate, n = 10.0, 900
    rng = np.random.default_rng(4)
    u = np.repeat(rng.uniform(0.0, 3.0, n // 30), 30)
    y = np.sqrt(u[0] + TRUE["bias"])
    out = []
    for value in u:
        out.append(y)
        target = np.sqrt(value + TRUE["bias"])
        y = solve_ivp(
            lambda t, x, target=target: (target - x) / TRUE["tau"],
            (0.0, 1.0 / rate),
            [y],
            rtol=1e-11,
            atol=1e-12,
        ).y[0, -1]
    return hybrid.Recording.from_arrays(v_in=u, w=GAIN * np.array(out) + OFFSET, rate=rate)


@pytest.fixture(scope="module")
def fitted_plugin(tmp_path_factory):
    path = tmp_path_factory.mktemp("plugin") / "valve.py"
    path.write_text(textwrap.dedent(PLUGIN))
    start = resolve_physics(f"{path}:SqrtLag")  # tau 1, bias 1
    result = hybrid.fit(hybrid.make_model("physics", simulation=start), _valve_recording(), progress=False)
    return path, result


def test_fit_recovers_the_planted_parameters_of_a_plugin(fitted_plugin):
    _, result = fitted_plugin
    assert result.parameters["tau"] == pytest.approx(TRUE["tau"], rel=1e-5)
    assert result.parameters["bias"] == pytest.approx(TRUE["bias"], rel=1e-5)
    assert result.parameters["gain"] == pytest.approx(GAIN, rel=1e-5)
    assert result.metrics["test"]["nmse"] < 1e-9


def test_a_fitted_plugin_model_saves_and_loads(fitted_plugin, tmp_path):
    path, result = fitted_plugin
    saved = hybrid.save_model(tmp_path / "valve.eqx", result.model)
    loaded = hybrid.load_model(saved)
    assert type(loaded.simulation) is type(result.model.simulation)
    v = np.linspace(0.0, 2.0, 50)
    np.testing.assert_array_equal(
        np.asarray(loaded.predict(v, 0.1)), np.asarray(result.model.predict(v, 0.1))
    )


def test_a_saved_plugin_model_loaded_without_its_file_names_the_flag_that_loads_it(fitted_plugin, tmp_path):
    """The real command line, a fresh process: --start-from a plug-in's model without --physics."""
    path, result = fitted_plugin
    saved = hybrid.save_model(tmp_path / "valve.eqx", result.model)
    record = _valve_recording()
    (tmp_path / "rec.csv").write_text(
        "v_in,w\n"
        + "".join(f"{a:.17g},{b:.17g}\n" for a, b in zip(np.asarray(record.v_in), np.asarray(record.w)))
    )
    done = run_hybrid(
        tmp_path,
        "fit",
        "rec.csv",
        "--columns",
        "input=v_in,output=w",
        "--rate",
        record.rate,
        "--model",
        "physics",
        "--start-from",
        saved,
    )
    assert done.returncode == 2 and "Traceback" not in done.stderr
    (line,) = done.stderr.strip().splitlines()
    assert "plug-in file valve.py" in line and "--physics path/to/valve.py:SqrtLag" in line


# --- the worked example ----------------------------------------------------------------------


def test_the_two_tank_example_matches_solve_ivp_and_differentiates_from_empty_tanks():
    sim = resolve_physics(str(ROOT / "examples" / "two_tank.py") + ":TwoTank")
    module = sys.modules[type(sim).__module__]
    assert sim.config() == {} and set(sim.frozen_by_default) == {"pump_flow", "area_1", "area_2"}
    p = {k: float(v) for k, v in sim.parameters().items()}
    c1, c2 = (p[k] * np.sqrt(2 * module.G) for k in ("outlet_1", "outlet_2"))

    def outflow(h):
        return h / np.sqrt(abs(h) + module.H_LAMINAR)

    dt, u = 0.1, np.repeat([0.0, 6.0, 2.0, 8.0, 0.0], 40)  # starts empty, fills, drains
    h, expected = np.zeros(2), []
    for value in u:
        expected.append(h[1])
        q = p["pump_flow"] * value

        def rate(t, x, q=q):
            return [
                (q - c1 * outflow(x[0])) / p["area_1"],
                (c1 * outflow(x[0]) - c2 * outflow(x[1])) / p["area_2"],
            ]

        h = solve_ivp(rate, (0.0, dt), h, method="DOP853", rtol=1e-12, atol=1e-12).y[:, -1]
    got = np.asarray(sim.simulate(u, dt))
    assert np.max(np.abs(got - expected)) <= 1e-6 * np.max(expected)
    grad = jax.grad(lambda raw: jnp.sum(_with_raw(sim, raw).simulate(u, dt)))(sim.raw)
    assert all(np.isfinite(float(g)) for g in grad.values())


def test_the_dc_motor_example_matches_solve_ivp_under_a_held_drive():
    sim = resolve_physics(str(ROOT / "examples" / "dc_motor.py") + ":DCMotor")
    p = {k: float(v) for k, v in sim.parameters().items()}
    assert set(sim.frozen_by_default) == {"resistance", "torque_constant", "viscous"}
    dt, u = 0.02, np.repeat([0.0, 6.0, -3.0, 12.0, 0.0], 40)
    x, expected = np.zeros(2), []
    for value in u:  # the output at a sample is the state there; the drive is held until the next one
        expected.append(x[1])

        def rate(t, x, v=value):
            i, w = x
            return [
                (v - p["resistance"] * i - p["torque_constant"] * w) / p["inductance"],
                (p["torque_constant"] * i - p["viscous"] * w) / p["inertia"],
            ]

        x = solve_ivp(rate, (0.0, dt), x, method="DOP853", rtol=1e-12, atol=1e-12).y[:, -1]
    got = np.asarray(sim.simulate(u, dt))
    # RK4, 4 steps per 20 ms sample against time constants of 24 ms and 0.4 s: 4e-8 of the range when written
    assert np.max(np.abs(got - expected)) <= 1e-6 * np.ptp(expected)
    grad = jax.grad(lambda raw: jnp.sum(_with_raw(sim, raw).simulate(u, dt)))(sim.raw)
    assert all(np.isfinite(float(g)) for g in grad.values())


def test_the_dc_motor_takes_a_fed_back_force_as_a_torque_on_its_shaft():
    """An inside effect's force is a torque on the shaft (N m, sized against the stall torque K·u/R), not a
    voltage off the drive: a cubic torque k·ω³ through `stiffness` against solve_ivp's motor with it."""
    sim = resolve_physics(str(ROOT / "examples" / "dc_motor.py") + ":DCMotor")
    p = {k: float(v) for k, v in sim.parameters().items()}
    k3, dt, u = 2e-5, 0.02, np.repeat([0.0, 6.0, -3.0, 12.0, 0.0], 40)
    stack = hybrid.EffectStack(sim, ["stiffness"], drive_unit="V").replace(stiffness_cube=k3)
    assert stack.force_unit == "N m" and stack.units["stiffness_cube"] == "(N m)/(rad/s)^3"
    x, expected = np.zeros(2), []
    for value in u:
        expected.append(x[1])

        def rate(t, x, v=value):
            i, w = x
            return [
                (v - p["resistance"] * i - p["torque_constant"] * w) / p["inductance"],
                (p["torque_constant"] * i - p["viscous"] * w - k3 * w**3) / p["inertia"],
            ]

        x = solve_ivp(rate, (0.0, dt), x, method="DOP853", rtol=1e-12, atol=1e-12).y[:, -1]
    got = np.asarray(stack.simulate(u, dt))
    assert np.max(np.abs(got - expected)) <= 1e-6 * np.ptp(expected)
    assert np.max(np.abs(got - np.asarray(sim.simulate(u, dt)))) > 0.05 * np.ptp(expected)  # it acts
    derived = stack.derived(u, dt)["stiffness"]["force_percent_of_drive"]
    stall = p["torque_constant"] * np.max(np.abs(u)) / p["resistance"]
    assert derived == pytest.approx(100 * k3 * np.max(np.abs(got)) ** 3 / stall, rel=1e-6)


def test_each_rc_name_means_one_network_on_every_command():
    """`rc` is the paper's Tustin network (make_model's default, fit's and sensitivity's --physics); `rc:zoh`
    is the exact-ZOH network diagnose starts from, from Python and from its --physics default alike."""
    from hybrid.cli import build_parser
    from hybrid.ipmc._defaults import diagnose_simulation

    rc, zoh = resolve_physics("rc"), resolve_physics("rc:zoh")
    assert (rc.method, zoh.method) == ("tustin", "zoh")
    assert eqx.tree_equal(rc, hybrid.make_model("physics").simulation)
    assert eqx.tree_equal(zoh, diagnose_simulation())
    assert float(zoh.parameters()["C_clamp"]) == pytest.approx(0.03, rel=1e-12)
    parser = build_parser()
    defaults = {
        command: parser.parse_args([command, "r.csv", "--out", "o"]).physics
        for command in ("fit", "diagnose", "sensitivity")
    }
    assert defaults == {"fit": "rc", "diagnose": "rc:zoh", "sensitivity": "rc"}
