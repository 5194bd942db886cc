"""Effects are plug-ins: one class owns its maths, units, starts and materiality; `diagnose` takes
`effects=` and the command line `--effects`.

The recordings here are made by independent references in numpy (a first-order lag's exact solution
for a drive held over each sample), never by the effects under test.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import ClassVar

import helpers as h
import jax.numpy as jnp
import numpy as np
import pytest

import hybrid
from hybrid import AbstractEffect, InputError, Positive, Real, encode

ROOT = Path(__file__).resolve().parents[1]
RATE, TAU, GAIN, OFFSET, NEGATIVE_CHANGE = 30.0, 0.5, 3.0, 0.2, -0.6


def _docs_effect() -> str:
    return h.docs_python_block("effects.md", "## An effect in one file", "## The interface")


def _lag(u: np.ndarray) -> np.ndarray:
    """The exact ZOH lag τ from rest (`helpers.zoh_lag`)."""
    return h.zoh_lag(u, 1.0 / RATE, TAU)


def _drive(seed: int, seconds: float) -> np.ndarray:
    rng = np.random.default_rng(seed)
    levels, holds = [], []
    while sum(holds) < seconds * RATE:
        levels.append(rng.uniform(-1.0, 1.0))
        holds.append(int(rng.integers(int(0.4 * RATE), int(2.0 * RATE))))
    return np.repeat(levels, holds)[: int(seconds * RATE)]


def test_the_docs_effect_imports_only_public_names():
    h.assert_public_imports_only(_docs_effect())


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """A lag driven through a drive whose negative half acts 40 % as strongly, 90 s at 30 Hz."""
    folder = tmp_path_factory.mktemp("lab")
    (folder / "asymmetric.py").write_text(_docs_effect())
    u = _drive(5, 90.0)
    x = _lag(u + NEGATIVE_CHANGE * np.minimum(u, 0.0))
    rng = np.random.default_rng(6)
    w = GAIN * x + OFFSET + 0.005 * np.ptp(GAIN * x) * rng.normal(size=u.size)
    hybrid.Recording.from_arrays(v_in=u, w=w, rate=RATE).save(folder / "lab.csv")
    return folder


def _hybrid(folder, *args):
    return h.run_hybrid(folder, *args)


def test_the_cli_finds_a_user_effect_through_effects(lab):
    run = _hybrid(
        lab,
        "diagnose",
        "lab.csv",
        "--physics",
        "lti:1",
        "--effects",
        "asymmetric.py:AsymmetricDrive,saturation",
        "--out",
        "report",
        "--quiet",
    )
    assert run.returncode == 0, run.stderr[-2000:]
    report = json.loads((lab / "report" / "report.json").read_text())
    assert report["cause"] == "asymmetric_drive", report["cause"]
    change = report["parameters"]["negative_gain_change"]
    assert change["value"] == pytest.approx(NEGATIVE_CHANGE, abs=0.05)
    assert change["unit"] == "1"
    assert report["settings"]["materiality"]["negative_change_percent"] == 10.0  # its own threshold
    assert report["warnings"] == []  # finite over all of its range: nothing to say about it
    assert "negative_gain_change" in run.stdout  # the CLI prints the plug-in's parameters by name

    # The extended model comes back loadable, the plug-in's module imported first (as --effects does).
    h.import_file(lab / "asymmetric.py", "lab_asymmetric")
    extended = hybrid.load_model(lab / "report" / "extended.eqx")
    assert [e.name for e in extended.simulation.effects] == ["asymmetric_drive", "frame_timing"]
    loaded = float(extended.simulation.parameters()["negative_gain_change"])
    assert loaded == pytest.approx(change["value"], rel=1e-9)
    baseline = hybrid.load_model(lab / "report" / "baseline.eqx")
    assert [e.name for e in baseline.simulation.effects] == ["frame_timing"]


def test_hybrid_fit_fits_a_chosen_effect_directly(lab):
    run = _hybrid(
        lab,
        "fit",
        "lab.csv",
        "--model",
        "physics",
        "--physics",
        "lti:1",
        "--effects",
        "asymmetric.py:AsymmetricDrive",
        "--param",
        "negative_gain_change=-0.3",
        "--out",
        "fit.eqx",
        "--json",
        "fit.json",
        "--quiet",
    )
    assert run.returncode == 0, run.stderr[-2000:]
    parameters = json.loads((lab / "fit.json").read_text())["parameters"]
    assert parameters["negative_gain_change"] == pytest.approx(NEGATIVE_CHANGE, abs=0.03)
    assert parameters["tau_1"] == pytest.approx(TAU, rel=0.05)


@pytest.mark.parametrize(
    "spec, words",
    [
        ("nope.py:X", "no file nope.py"),
        ("asymmetric.py:Missing", "has no class Missing; it defines AsymmetricDrive"),
        ("friction", "not an effect I know"),
        ("asymmetric.py:AsymmetricDrive,asymmetric.py:AsymmetricDrive", "effects named twice"),
        # a probe's own physics given to --effects: "it defines no AbstractEffect subclass", no way on
        (f"{ROOT}/examples/two_tank.py:TwoTank", "TwoTank is a simulation: give it as --physics"),
    ],
)
def test_a_bad_effects_flag_gets_one_line(lab, spec, words, monkeypatch, capsys):
    """The command line's own entry point, in this process (the subprocess test above covers the rest)."""
    from hybrid.cli import main

    monkeypatch.chdir(lab)
    code = main(["diagnose", "lab.csv", "--physics", "lti:1", "--effects", spec, "--out", "bad", "--quiet"])
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and lines[0].startswith("hybrid: error:"), lines
    assert words in lines[0], lines[0]
    assert not (lab / "bad").exists()  # nothing written before it succeeded


def test_a_plug_in_effect_refused_by_its_checks_is_named_by_its_file(lab, monkeypatch, capsys):
    """A probe's variants of one class in several files: "effect SlewLimit: SlewLimit.place must be ..."
    did not say which file failed; the line now starts with the --effects spec, as a class typo's does."""
    from hybrid.cli import main

    monkeypatch.chdir(lab)
    source = (lab / "asymmetric.py").read_text()
    (lab / "wrong_place.py").write_text(
        source.replace('place: ClassVar[str] = "drive"', 'place: ClassVar[str] = "input"')
    )
    assert "input" in (lab / "wrong_place.py").read_text()
    code = main(
        [
            "diagnose",
            "lab.csv",
            "--physics",
            "lti:1",
            "--effects",
            "builtins,wrong_place.py:AsymmetricDrive",
            "--out",
            "bad",
        ]
    )
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1, lines
    assert lines[0].startswith(
        "hybrid: error: --effects wrong_place.py:AsymmetricDrive: effect AsymmetricDrive:"
    )
    assert "place must be one of drive, inside, output, got 'input'" in lines[0]


_LATE_NAN = """
from typing import ClassVar
import jax.numpy as jnp
from hybrid import AbstractEffect, Positive, encode


class LateNaN(AbstractEffect):
    raw: dict
    name: ClassVar[str] = "late_nan"
    constraints: ClassVar = {"gain": Positive()}
    units: ClassVar = {"gain": "1"}
    defaults: ClassVar = {"gain": 1.0}

    def __init__(self, **values):
        self.raw = encode({**self.defaults, **values}, self.constraints, self.name)

    def apply(self, s, dt):  # finite on the 64-sample probe, NaN from sample 200 of a recording on
        return jnp.where(jnp.arange(s.shape[0]) >= 200, jnp.nan, s * self.parameters()["gain"])
"""


_GREEDY = (
    _LATE_NAN.replace("class LateNaN", "class Greedy")
    .replace('"late_nan"', '"greedy"')
    .replace(
        "    def apply(self, s, dt):",
        """    def starts(self, context):  # one per 50 samples of the signal: more on a recording than on the probe
        return [{"gain": 1.0 + 0.01 * k} for k in range(1 + len(context.signal) // 50)]

    def apply(self, s, dt):""",
    )
)


_NAN_START = (
    _LATE_NAN.replace("class LateNaN", "class NaNStart")
    .replace('"late_nan"', '"nan_start"')
    .replace(
        "    def apply(self, s, dt):",
        """    def starts(self, context):  # a start out of its own range, seen only when the search builds it
        return [{"gain": 1.0}, {"gain": float(context.duration) * float("nan")}]

    def apply(self, s, dt):""",
    )
)


@pytest.mark.parametrize(
    "source, cls, words",
    [
        # past the probe, every lane of the effect is NaN: it was numpy's 'All-NaN slice encountered'
        (_LATE_NAN, "LateNaN", "effect LateNaN: every start of its fit gives non-finite"),
        # it said 'nan_start parameter gain must be positive, got nan', naming neither method nor class
        (_NAN_START, "NaNStart", "effect NaNStart: a start from starts(context) or screened_starts(context)"),
        # the lanes are counted on a probe: the message named no effect, now it names the one that varies
        (_GREEDY, "Greedy", "effect Greedy: starts(context) gave"),
    ],
)
def test_an_effect_that_misbehaves_only_on_the_recording_is_named_in_one_line(
    lab, monkeypatch, capsys, source, cls, words
):
    from hybrid.cli import main

    (lab / f"{cls.lower()}.py").write_text(source)
    monkeypatch.chdir(lab)
    argv = ["diagnose", "lab.csv", "--physics", "lti:1", "--effects", f"{cls.lower()}.py:{cls}", "--out", cls]
    code = main([*argv, "--quiet"])
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1, lines
    assert lines[0].startswith("hybrid: error: ") and words in lines[0], lines
    assert not (lab / cls).exists()


_LOW_NAN = (
    _LATE_NAN.replace("class LateNaN", "class LowNaN")
    .replace('"late_nan"', '"low_nan"')
    .replace(
        '        return jnp.where(jnp.arange(s.shape[0]) >= 200, jnp.nan, s * self.parameters()["gain"])',
        '        g = self.parameters()["gain"]\n        return jnp.where(g < 0.5, jnp.nan, s * g)  # defined only above 0.5',
    )
)


def test_a_fit_started_where_an_effect_is_not_finite_names_the_effect_and_its_file(lab, monkeypatch, capsys):
    """A probe's slew limit, NaN below a rate of 3 V/s, fitted from 2: "the simulation EffectStack returns
    non-finite values … make its simulate finite" named neither the effect, its file nor its method."""
    from hybrid.cli import main

    assert "g < 0.5" in _LOW_NAN
    (lab / "low_nan.py").write_text(_LOW_NAN)
    monkeypatch.chdir(lab)
    argv = ["fit", "lab.csv", "--model", "physics", "--physics", "lti:1", "--effects", "low_nan.py:LowNaN"]
    code = main([*argv, "--param", "gain=0.2", "--max-steps", "3", "--quiet", "--out", "m.eqx"])
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip() and "warning" not in line]
    assert code == 2 and len(lines) == 1, lines
    assert lines[0].startswith("hybrid: error: --effects low_nan.py:LowNaN: effect LowNaN (on the output)"), (
        lines
    )
    assert "with its start parameters (gain=0.2)" in lines[0] and "make LowNaN.apply finite" in lines[0]
    assert not (lab / "m.eqx").exists()


_HALF_DEFINED = '''
import jax.numpy as jnp
from asymmetric import AsymmetricDrive


class HalfDefined(AsymmetricDrive):
    """The docs' effect with a square root in it: NaN for a change below -0.3 (the truth is -0.6)."""

    name = "half_defined"

    def apply(self, u, dt):
        g = self.parameters()["negative_gain_change"]
        return u + jnp.sqrt(g + 0.3) ** 2 * jnp.minimum(u, 0.0) - 0.3 * jnp.minimum(u, 0.0)

    def starts(self, context):
        return [{"negative_gain_change": -0.5}, {"negative_gain_change": 0.5}]
'''


def test_an_effect_not_finite_over_part_of_its_range_is_reported_not_searched_in_silence(
    lab, monkeypatch, capsys
):
    """Its lanes step around where apply is NaN, and the search names nothing: the report must say why.

    The lab's truth (a change of -0.6) lies where the plug-in's apply is NaN: before,
    the report said only that no effect passes the rules, which hides the plug-in's bug.
    """
    from hybrid.cli import main

    (lab / "half_defined.py").write_text(_HALF_DEFINED)
    monkeypatch.chdir(lab)  # its module imports the docs' effect beside it: the plug-in's folder is searched
    code = main(["diagnose", "lab.csv", "--physics", "lti:1", "--effects", "half_defined.py:HalfDefined",
                 "--out", "half", "--quiet"])  # fmt: skip
    assert code == 0
    warned = [line for line in capsys.readouterr().out.splitlines() if line.startswith("warning: ")]
    assert len(warned) == 1, warned
    assert "effect HalfDefined (half_defined): its predictions were not finite" in warned[0], warned
    assert "1 of its 2 starts (moved towards its defaults)" in warned[0], warned
    report = json.loads((lab / "half" / "report.json").read_text())
    assert report["warnings"] == [warned[0].removeprefix("warning: ")]
    assert "**Warning:** effect HalfDefined" in (lab / "half" / "report.md").read_text()


def test_only_a_plugin_effect_is_told_to_make_its_apply_finite():
    """A limit the library makes for a plug-in's velocity state escapes for some values (a new user's
    pendulum read "effect StateLimit (limit_velocity): … make apply finite", advice no user could follow);
    a plug-in's own effect that meets NaN is told so."""
    from types import SimpleNamespace

    from hybrid.discovery._inside_effects import StateLimit
    from hybrid.discovery._step import nonfinite_warnings

    limit, own = StateLimit("velocity"), _Scale()
    tally = {"starts_moved": 0, "starts": 4, "steps_refused": 9, "steps": 40}
    step = SimpleNamespace(nonfinite={limit.name: tally, own.name: tally})
    (warning,) = nonfinite_warnings([step], [limit, own])
    assert (
        warning.startswith("effect _Scale (scale): its predictions were not finite")
        and "9 of the 40" in warning
    )


# --------------------------------------------------------------------------- #
# The interface, in Python
# --------------------------------------------------------------------------- #


class _Scale(AbstractEffect):
    raw: dict
    name: ClassVar[str] = "scale"
    constraints: ClassVar = {"scale_factor": Real()}
    units: ClassVar = {"scale_factor": "1/{signal}"}
    defaults: ClassVar = {"scale_factor": 0.0}

    def __init__(self, **values):
        self.raw = encode({**self.defaults, **values}, self.constraints, self.name)

    def apply(self, s, dt):
        return s * (1.0 + self.parameters()["scale_factor"])


class _WrongShape(_Scale):
    name: ClassVar[str] = "wrong_shape"

    def apply(self, s, dt):
        return s[:-1]


class _Nowhere(_Scale):
    name: ClassVar[str] = "nowhere"
    place: ClassVar[str] = "between"


class _NoRole(_Scale):
    name: ClassVar[str] = "no_role"
    place: ClassVar[str] = "inside"
    role: ClassVar[str] = "push"


class _NoUnits(_Scale):
    name: ClassVar[str] = "no_units"
    units: ClassVar = {}


class _TypoStarts(_Scale):
    name: ClassVar[str] = "typo_starts"

    def start(self, context):  # diagnose reads `starts`: this one would be ignored in silence
        return [{"scale_factor": 2.0}]


class _UnitsMisspelt(_Scale):
    name: ClassVar[str] = "units_misspelt"
    units: ClassVar = {"scalefactor": "1"}


class _NoConstraint(_Scale):
    name: ClassVar[str] = "no_constraint"
    constraints: ClassVar = {}


class _Saturation(_Scale):  # a plug-in named like a built-in
    name: ClassVar[str] = "saturation"


class _NaNs(_Scale):
    name: ClassVar[str] = "nans"

    def apply(self, s, dt):
        return s * jnp.nan


class _Integers(_Scale):
    name: ClassVar[str] = "integers"

    def apply(self, s, dt):
        return jnp.round(s).astype(jnp.int32)


class _MaterialSaysYes(_Scale):
    name: ClassVar[str] = "says_yes"

    def material(self, derived, parameters, thresholds):
        return "yes"


class _DerivedNaN(_Scale):
    name: ClassVar[str] = "derived_nan"

    def derived(self, s, dt):
        return {"size": float("nan")}


class _Numpy(_Scale):
    name: ClassVar[str] = "numpy_inside"

    def apply(self, s, dt):  # numpy on the signal: runs eagerly, fails under jit
        return jnp.asarray(np.clip(np.asarray(s), -1.0, 1.0))


class _NoDefault(_Scale):
    name: ClassVar[str] = "no_default"
    defaults: ClassVar = {}


class _TypoUnit(_Scale):
    name: ClassVar[str] = "typo_unit"
    units: ClassVar = {"scale_factor": "1/{signl}"}


class _KeepsHalf(_Scale):
    name: ClassVar[str] = "keeps_half"
    n_kept: ClassVar = 0.5


class _ClassConstraint(_Scale):  # the class Positive for its instance Positive()
    name: ClassVar[str] = "class_constraint"
    constraints: ClassVar = {"scale_factor": Positive}


class _StartTypo(_Scale):
    name: ClassVar[str] = "start_typo"

    def starts(self, context):
        return [{"scale_factr": 0.1}]


@pytest.mark.parametrize(
    "effects, words",
    [
        (["friction"], "unknown effect 'friction':"),
        (["drive_evn"], "unknown effect 'drive_evn' (did you mean 'drive_even'?)"),
        # a new user's mistakes (the messages said 'missing parameter(s)' from inside encode, nothing, and
        # 'must return a non-empty list of dicts' without the key)
        ([_NoDefault], "_NoDefault.defaults has no entry for ['scale_factor']; add them"),
        (
            [_Numpy],
            "runs on numbers but not under jax.jit (TracerArrayConversionError); write it with jax.numpy",
        ),
        ([_TypoUnit], "units['scale_factor'] = '1/{signl}' has the placeholder {signl}: write {signal}"),
        (
            [_ClassConstraint],
            "the constraint for scale_factor is the class Positive, not one of its instances",
        ),
        ([_StartTypo], "starts(context) gave 'scale_factr', not a parameter of it (scale_factor)"),
        ([_KeepsHalf], "_KeepsHalf.n_kept must be a whole number ≥ 0 (0: every lane runs), got 0.5"),
        ([_WrongShape], "must return one finite value per sample"),
        ([_Nowhere], "place must be one of drive, inside, output"),
        ([_NoRole], "role must be one of feedback, limit"),
        ([_NoUnits], "units has no entry for ['scale_factor']"),
        ([_TypoStarts], "defines 'start', which diagnose never reads (did you mean 'starts'?)"),
        ([_UnitsMisspelt], "(units names ['scalefactor'], which is not a parameter: misspelt?)"),
        ([_NoConstraint], "defaults names ['scale_factor'], which _NoConstraint.constraints lacks"),
        (["builtins", _Saturation], "a plug-in named like the built-in 'saturation'"),
        ([_NaNs], "returned 64 non-finite values of 64"),
        ([_Integers], "returned int32 values: return floating point"),
        ([_MaterialSaysYes], "must return (bool, str)"),
        ([_DerivedNaN], "derived(s, dt) must return a dict of finite numbers"),
        ([int], "not an AbstractEffect subclass"),
        (["builtins", "slew.py:SlewLimit"], "in Python, import the class"),
        (["saturation", "saturation"], "effects named twice"),
        ([], "effects is empty"),
    ],
)
def test_resolve_effects_refuses_a_broken_effect_in_one_line(effects, words):
    with pytest.raises(InputError) as caught:
        hybrid.resolve_effects(effects)
    assert words in str(caught.value) and "\n" not in str(caught.value)


def test_resolve_effects_defaults_to_every_builtin_in_order():
    outside = [n for n, cls in hybrid.EFFECTS.items() if cls.place != "inside"]
    assert [e.name for e in hybrid.resolve_effects()] == outside  # no simulation: nothing inside
    mixed = hybrid.resolve_effects(["saturation", _Scale])
    assert [e.name for e in mixed] == ["saturation", "scale"]
    every = hybrid.resolve_effects(["builtins", _Scale])  # as --effects builtins,file.py:Scale
    assert [e.name for e in every] == [*outside, "scale"]
    given = _Scale(scale_factor=0.5)
    assert hybrid.resolve_effects([given])[0] is given  # an instance keeps its values


def test_units_follow_the_signal_each_effect_acts_on():
    stack = hybrid.EffectStack(
        hybrid.RCNetwork(), ("drive_dead_zone", "saturation", _Scale()), drive_unit="kV"
    )
    units = stack.units
    assert units["drive_dead_zone_width"] == "kV"  # on the drive
    drive_side = hybrid.EffectStack(
        hybrid.RCNetwork(), ("drive_saturation", "drive_even", "backlash"), drive_unit="kV"
    )
    assert drive_side.units["drive_saturation_pos_curvature"] == "1/kV"
    assert drive_side.units["drive_even_coefficient"] == "1/kV"
    assert drive_side.units["backlash_half_width"] == "kV"
    # on the RC network's output: V_o, a divider of the drive, is in the drive's unit
    assert units["saturation_pos_curvature"] == "1/kV"
    assert units["scale_factor"] == "1/kV"
    assert hybrid.EffectStack(hybrid.RCNetwork(), ("saturation",)).units["saturation_pos_curvature"] == "1/V"
    lti = hybrid.EffectStack(hybrid.LTI(1), ("saturation",), drive_unit="kV")
    assert lti.units["saturation_pos_curvature"] == "1/kV"  # LTI's output is in the drive's unit
    # a simulation that does not say: tests/test_plugin_diagnose.py's Lag, "1/(unit of S)"
    # a compound unit is one factor of a larger one: 1/(rad/s), not 1/rad/s
    speed = hybrid.EFFECTS["hysteresis"]().units_for("rad/s", "V")
    assert speed == {
        "hysteresis_height": "rad/s",
        "hysteresis_rate": "1/(rad/s)",
        "hysteresis_initial_state": "1",
    }
    assert hybrid.EFFECTS["baseline_drift"]().units_for("m/s")["baseline_curvature_per_min2"] == "(m/s)/min²"
    readout = hybrid.LinearReadout()
    assert readout.units_for("rad/s", "rad/s") == {"gain": "1", "offset": "rad/s"}  # w is S itself, rescaled
    assert readout.units_for("V", "mm")["gain"] == "mm/V"
    assert readout.units_for("m/s", "N")["gain"] == "N/(m/s)"


class _Level(hybrid.LTI):
    """A first-order lag whose output is a level in cm (a tank read by a sensor in volts)."""

    output_unit: ClassVar[str] = "cm"


def test_a_linear_readouts_units_follow_w_and_the_simulations_output(tmp_path):
    """gain is w's unit per the simulation's output's, never a hard-coded mm/V (the tanks read "mm/V")."""
    level = hybrid.make_model("physics", simulation=_Level(1))
    assert (level.units_in("V")["gain"], level.units_in("V")["offset"]) == ("V/cm", "V")
    rc = hybrid.make_model("physics", simulation=hybrid.RCNetwork())
    assert rc.units["gain"] == "mm/V"  # the paper's case
    assert rc.units_in("µm", drive_unit="mV")["gain"] == "µm/mV"  # V_o in the drive's unit
    lag = hybrid.make_model("physics", simulation=hybrid.LTI(1))
    assert lag.units_in("N", drive_unit="kV")["gain"] == "N/kV"  # LTI's output is in the drive's unit
    # a simulation that names no output unit: tests/test_plugin_diagnose.py's Lag, "N/(unit of S)"
    # fit reports them in the recording's declared units
    t = np.arange(300) / 10.0
    u = np.sin(0.7 * t) + 0.5 * np.sign(np.sin(0.21 * t))
    rec = hybrid.Recording(
        t=t, v_in=u, w=0.3 * u + 1.0, metadata={"units": {"t": "s", "v_in": "V", "w": "V"}}
    )
    result = hybrid.fit(level, rec, solver=hybrid.LevenbergMarquardt(max_steps=3), progress=False)
    assert (result.units["gain"], result.units["offset"]) == ("V/cm", "V")
    # ... and so do the fitted model's own units, saved with it and loaded back (they read mm)
    assert result.model.units == result.units
    path = hybrid.save_model(tmp_path / "level.eqx", result.model)
    assert json.loads(Path(f"{path}.json").read_text())["units"]["gain"] == "V/cm"
    assert hybrid.load_model(path).units == result.units
    batch = hybrid.fit_batch(level, [rec], solver=hybrid.LevenbergMarquardt(max_steps=3))
    assert batch[0].model.units["offset"] == "V"


def test_a_drive_side_effect_acts_before_the_simulation():
    """EffectStack(drive dead zone) = the simulation of the dead-zoned drive (numpy reference)."""
    u = _drive(1, 20.0)
    width = 0.3
    inner = hybrid.LTI(1)
    stack = hybrid.EffectStack(inner, ("drive_dead_zone",)).replace(drive_dead_zone_width=width)
    zoned = np.where(np.abs(u) <= width, 0.0, u - np.sign(u) * width)
    expected = np.asarray(inner.simulate(jnp.asarray(zoned), 1.0 / RATE))
    np.testing.assert_allclose(np.asarray(stack.simulate(jnp.asarray(u), 1.0 / RATE)), expected, atol=1e-12)
    derived = stack.derived(jnp.asarray(u), 1.0 / RATE)["drive_dead_zone"]
    assert derived["drive_dead_zone_percent"] == pytest.approx(100 * width / np.max(np.abs(u)))
    # Backlash: the simulation of the played drive (a loop, not the library's scan).
    played, y = [], u[0]  # the play starts centred on the first drive
    for value in u:
        y = min(max(y, value - width), value + width)
        played.append(y)
    stack = hybrid.EffectStack(inner, ("backlash",)).replace(backlash_half_width=width)
    expected = np.asarray(inner.simulate(jnp.asarray(played), 1.0 / RATE))
    np.testing.assert_allclose(np.asarray(stack.simulate(jnp.asarray(u), 1.0 / RATE)), expected, atol=1e-12)


def test_baseline_drift_is_an_additive_trend_in_minutes():
    dt = 1.0 / RATE
    s = np.sin(np.arange(1800) * dt)
    effect = hybrid.EFFECTS["baseline_drift"](
        baseline_slope_per_min=0.2, baseline_curvature_per_min2=-0.05, baseline_cubic_per_min3=0.03
    )
    t = np.arange(1800) * dt / 60.0
    trend = 0.2 * t - 0.05 * t**2 + 0.03 * t**3
    np.testing.assert_allclose(np.asarray(effect.apply(jnp.asarray(s), dt)), s + trend, atol=1e-12)
    assert effect.derived(s, dt)["baseline_percent_of_range"] == pytest.approx(
        100 * np.ptp(trend) / np.ptp(s)
    )
    # A baseline that sinks and comes back above its start moves from its lowest to its highest (the
    # readout's offset takes its level): a probe's sine-and-ramp drift of 6.8 % was read 4.1 % from its start.
    sinks = hybrid.EFFECTS["baseline_drift"](baseline_slope_per_min=-0.3, baseline_curvature_per_min2=0.5)
    trend = -0.3 * t + 0.5 * t**2  # down to -0.045 at 0.3 min, up to +0.2 at 1 min
    assert sinks.derived(s, dt)["baseline_percent_of_range"] == pytest.approx(100 * np.ptp(trend) / np.ptp(s))
    assert np.ptp(trend) > np.max(np.abs(trend)) + 0.04  # the reading from its start would be short


def test_a_hysteresis_loop_the_recording_never_closes_is_not_material():
    """Rate × range: a sweep across the range moves the Bouc–Wen state by tanh(k·ptp(s)) at most."""
    dt = 1.0 / RATE
    s = 2.0 * np.sin(2 * np.pi * 0.2 * np.arange(1800) * dt)  # ptp 4 V
    hysteresis = hybrid.EFFECTS["hysteresis"]
    thresholds = dict(hysteresis.thresholds)
    for rate, closes in ((2.0, True), (0.3, True), (0.2, False), (0.01, False)):
        effect = hysteresis(hysteresis_height=0.4, hysteresis_rate=rate)
        derived = effect.derived(s, dt)
        assert derived["loop_rate_times_range"] == pytest.approx(rate * np.ptp(s))
        assert derived["loop_height_percent_of_range"] == pytest.approx(100 * 0.8 / np.ptp(s))
        ok, why = effect.material(derived, {}, thresholds)
        assert bool(ok) is closes, (rate, why)
    # the state's own excursion: across its whole range when k·ptp(s) = 8, within 5 % of it at 0.04
    for rate, low, high in ((2.0, 1.9, 2.0), (0.01, 0.0, 0.1)):
        u = (
            np.asarray(hysteresis(hysteresis_height=0.4, hysteresis_rate=rate).apply(jnp.asarray(s), dt)) - s
        ) / 0.4
        assert low <= np.ptp(u) <= high, (rate, np.ptp(u))
    why = hysteresis(hysteresis_height=0.4, hysteresis_rate=0.01).material(
        hysteresis(hysteresis_height=0.4, hysteresis_rate=0.01).derived(s, dt), {}, thresholds
    )[1]
    assert "never closes" in why and "0.04" in why
    # a user who knows better lowers the threshold through the materiality settings
    settings = hybrid.DiagnoseSettings(materiality={"loop_rate_times_range": 0.01})
    merged = settings.materiality_for(hybrid.resolve_effects())
    effect = hysteresis(hysteresis_height=0.4, hysteresis_rate=0.2)
    assert effect.material(effect.derived(s, dt), {}, merged)[0]


def test_a_loop_on_a_signal_that_never_turns_back_is_not_material():
    """A loop shows only where the signal turns back: along one branch it is a static curve."""
    from hybrid.discovery._effects import signal_turn

    rising = np.repeat(np.linspace(0.2, 2.0, 10), 30)
    assert signal_turn(rising) == 0.0 and signal_turn(-rising) == 0.0
    hump = np.concatenate([np.linspace(0.0, 3.0, 50), np.linspace(3.0, 1.0, 50)])
    assert signal_turn(hump) == pytest.approx(2.0)  # the way back; up 3, down 2
    assert signal_turn(np.concatenate([hump, hump + 0.5])) == pytest.approx(2.5)  # the largest: 3 to 0.5
    hysteresis = hybrid.EFFECTS["hysteresis"]
    effect = hysteresis(hysteresis_height=5.0, hysteresis_rate=2.0)  # k·range 3.6: it would close
    ok, why = effect.material(effect.derived(rising, 1.0 / RATE), {}, dict(hysteresis.thresholds))
    assert not ok and "never turns back far enough to show a loop: its largest turn is 0 %" in why
    ok, _ = effect.material(effect.derived(hump, 1.0 / RATE), {}, dict(hysteresis.thresholds))
    assert ok  # the turn 67 % of the range
    wiggle = rising + np.where(np.arange(rising.size) == 100, -0.005, 0.0)  # a 0.3 % turn, k·turn 50
    fast = hysteresis(hysteresis_height=0.1, hysteresis_rate=1e4)
    ok, why = fast.material(fast.derived(wiggle, 1.0 / RATE), {}, dict(hysteresis.thresholds))
    assert not ok and "0.28 % of its range (needs ≥ 10 %)" in why, why


def test_a_saturation_under_a_rising_staircase_is_not_named_a_loop():
    """A probe's output saturation L·tanh(y/L) behind a lag under a rising staircase: "hysteresis", a loop
    838 % of the range, "what remains is measurement noise" (the drive never went down)."""
    rng = np.random.default_rng(3)
    u = np.repeat(np.linspace(0.2, 2.0, 10), 150)  # 50 s at 30 Hz, the level rising with time
    y = 1.5 * np.tanh(_lag(u) / 1.5)
    w = y + 0.01 * rng.normal(size=u.size)
    found = hybrid.diagnose(
        hybrid.Recording.from_arrays(v_in=u, w=w, rate=RATE),
        simulation=hybrid.LTI(1),
        effects=["hysteresis", "saturation"],
    )
    assert "hysteresis" not in found.causes, found.summary()
    loops = [c for step in found.steps for c in step.candidates if c.name == "hysteresis"]
    assert loops and all(not c.material for c in loops)
    assert any("never turns back" in r for c in loops for r in c.reasons), [c.reasons for c in loops]
    # a loop on one branch is no loop at all, not one too small to count: never offered with a threshold
    assert "hysteresis" not in {small["name"] for small in found.too_small}
    assert "one branch, no loop" in hybrid.EFFECTS["hysteresis"]().unlike({"turn_percent_of_range": 0.0})
    assert hybrid.EFFECTS["hysteresis"]().unlike({"turn_percent_of_range": 5.0}) is None  # a size: settable


def test_materiality_overrides_name_a_threshold_a_searched_effect_has():
    settings = hybrid.DiagnoseSettings(materiality={"delay_samples": 2.0})
    merged = settings.materiality_for(hybrid.resolve_effects())
    assert merged["delay_samples"] == 2.0 and merged["relaxation_percent"] == 10.0
    with pytest.raises(InputError, match="no searched effect has"):
        hybrid.DiagnoseSettings(materiality={"delay_sample": 2.0}).materiality_for(hybrid.resolve_effects())


def test_a_switched_off_effect_is_not_evaluated_and_a_switch_scales_its_change():
    """`EffectStack` skips an effect whose switch is 0 (its NaN never reaches the output) and adds
    ``on·(effect(s) − s)`` otherwise; its parameters then have zero Jacobian columns."""
    import jax

    class Poison(AbstractEffect):
        raw: dict
        name: ClassVar[str] = "poison"
        constraints: ClassVar = {"poison_level": Real()}
        units: ClassVar = {"poison_level": "1"}
        defaults: ClassVar = {"poison_level": 0.0}

        def __init__(self):
            self.raw = encode(self.defaults, self.constraints, self.name)

        def apply(self, s, dt):
            return s * jnp.nan

    u = jnp.asarray(_drive(2, 10.0))
    inner = hybrid.LTI(1)
    s = np.asarray(inner.simulate(u, 1.0 / RATE))
    stack = hybrid.EffectStack(inner, (Poison(), _Scale(scale_factor=0.4)), active=jnp.array([0.0, 0.5]))
    out = np.asarray(stack.simulate(u, 1.0 / RATE))
    np.testing.assert_allclose(out, s + 0.5 * (1.4 * s - s), rtol=1e-12, atol=1e-12)

    def output(raw, active):
        return stack.with_raw({"scale_factor": raw}).with_active(active).simulate(u, 1.0 / RATE)

    raw = stack.raw["scale_factor"]
    assert not np.any(np.asarray(jax.jacfwd(output)(raw, jnp.array([0.0, 0.0]))))  # off: no column
    assert np.any(np.asarray(jax.jacfwd(output)(raw, jnp.array([0.0, 1.0]))))  # on: a column


def test_hybrid_fit_starts_a_built_in_effect_where_its_fit_can_move(tmp_path):
    """A lag clipped softly (12·tanh(y/6), numpy) fitted with `--effects saturation` from the CLI.

    From its default curvature 0 LM cannot move (tanh(κs)/κ is even in κ: zero gradient), and the
    fit kept the straight line; from the effect's first start it finds the curvature. An effect the
    record does not hold ends too small to count, and the fit says so.
    """
    rng = np.random.default_rng(2)
    n = 900
    u = np.repeat(rng.uniform(-10, 10, n // 30 + 1), 30)[:n]
    y = 12.0 * np.tanh(_lag(u) / 6.0) + 0.004 * rng.normal(size=n)
    table = np.c_[np.arange(n) / RATE, u, y]
    np.savetxt(tmp_path / "clipped.csv", table, delimiter=",", header="t,v_in,w\ns,V,mm", comments="")
    common = ("fit", "clipped.csv", "--model", "physics", "--physics", "lti:1", "--quiet")
    run = _hybrid(tmp_path, *common, "--effects", "saturation", "--out", "s.eqx", "--json", "s.json")
    assert run.returncode == 0, run.stderr[-2000:]
    fitted = json.loads((tmp_path / "s.json").read_text())
    for side in ("pos", "neg"):  # κ = 1/6 per V of the lag's output, up to what the readout's gain takes
        assert fitted["parameters"][f"saturation_{side}_curvature"] == pytest.approx(1 / 6, rel=0.25)
    assert fitted["metrics"]["test"]["nmse_variance"] < 1e-4
    assert not [w for w in fitted["warnings"] if "too small" in w]

    lag = np.c_[np.arange(n) / RATE, u, 2.0 * _lag(u) + 0.004 * rng.normal(size=n)]
    np.savetxt(tmp_path / "lag.csv", lag, delimiter=",", header="t,v_in,w\ns,V,mm", comments="")
    run = _hybrid(tmp_path, *common[:1], "lag.csv", *common[2:], "--effects", "hysteresis", "--out", "h.eqx")
    assert run.returncode == 0, run.stderr[-2000:]
    assert "hysteresis is too small in the fitted model to count as a cause" in run.stdout


def test_hybrid_fit_starts_a_line_at_the_residuals_strongest_line(tmp_path):
    """A 7.3 Hz pick-up on a lag's output (numpy), fitted with `--effects line` from the CLI.

    The line's frequency has a basin about one bin of the spectrum wide (1/T): from its 1 Hz default
    the fit ended at 0.54 Hz with nothing (`line is too small`). Its first start now reads the
    strongest line of the recording mapped onto the simulation's output (w ≈ g·y + c).
    """
    rng = np.random.default_rng(4)
    n = 900
    t = np.arange(n) / RATE
    u = np.repeat(rng.uniform(-1, 1, n // 15 + 1), 15)[:n]
    amplitude = 0.05 * np.ptp(GAIN * _lag(u))  # 5 % of the range
    y = GAIN * _lag(u) + OFFSET + amplitude * np.sin(2 * np.pi * 7.3 * t + 0.7)
    table = np.c_[t, u, y + 0.004 * np.ptp(y) * rng.normal(size=n)]
    np.savetxt(tmp_path / "hum.csv", table, delimiter=",", header="t,v_in,w\ns,V,mm", comments="")
    run = _hybrid(
        tmp_path,
        *("fit", "hum.csv", "--model", "physics", "--physics", "lti:1", "--effects", "line"),
        *("--out", "l.eqx", "--json", "l.json", "--quiet"),
    )
    assert run.returncode == 0, run.stderr[-2000:]
    fitted = json.loads((tmp_path / "l.json").read_text())
    p = fitted["parameters"]
    # 30 s: a bin is 1/30 Hz; the fit pins the frequency far inside it
    assert p["line_frequency_hz"] == pytest.approx(7.3, abs=0.005)
    size = np.hypot(p["line_cos"], p["line_sin"]) * p["gain"]  # in w's unit through the readout's gain
    assert size == pytest.approx(amplitude, rel=0.05)
    assert np.arctan2(-p["line_sin"], p["line_cos"]) == pytest.approx(0.7 - np.pi / 2, abs=0.05)
    assert not [w for w in fitted["warnings"] if "too small" in w]


def test_a_unit_template_that_brackets_its_placeholder_is_not_bracketed_twice():
    """A probe's drag effect wrote ``{drive}/({signal})^2`` and read ``V/((rad/s))^2``: the library brackets
    a compound unit itself (``1/{signal}`` reads ``1/(rad/s)``), so a template's own brackets take it as is."""
    from hybrid.core._simulation import substitute_unit

    assert substitute_unit("{drive}/({signal})^2", "{signal}", "rad/s") == "{drive}/(rad/s)^2"
    assert substitute_unit("{drive}/({signal})^2", "{signal}", "rad") == "{drive}/rad^2"
    assert substitute_unit("1/{signal}", "{signal}", "rad/s") == "1/(rad/s)"
    assert substitute_unit("{signal}", "{signal}", "rad/s") == "rad/s"


#: A user's limit from below, written as a lab would: nothing in the library names it.
FLOOR = '''
"""A floor under a state: it cannot fall below a level (a stop under a position, a level at its outlet)."""

from typing import ClassVar

import jax
import numpy as np

from hybrid import AbstractEffect, Real, encode


class Floor(AbstractEffect):
    """Inside the dynamics: the state lag_1 held at or above floor_level after every step."""

    raw: dict
    name: ClassVar[str] = "floor"
    place: ClassVar[str] = "inside"
    role: ClassVar[str] = "limit"
    acts_on: ClassVar[str] = "lag_1"
    constraints: ClassVar = {"floor_level": Real()}
    units: ClassVar = {"floor_level": "{signal}"}
    defaults: ClassVar = {"floor_level": -1.0}
    thresholds: ClassVar = {"cut_percent_of_range": 3.0}

    def __init__(self, **values):
        self.raw = encode({**self.defaults, **values}, self.constraints, self.name)

    def apply(self, z, dt):
        level = self.parameters()["floor_level"]
        return level + 1e-3 * jax.nn.softplus((z - level) / 1e-3)

    def starts(self, context):
        z = np.asarray(context.signal)
        low, span = float(np.min(z)), float(np.ptp(z))
        return [{"floor_level": low + 0.1 * span}, {"floor_level": low + 0.3 * span}]

    def material(self, derived, parameters, thresholds):
        size, need = derived["cut_percent_of_range"], thresholds["cut_percent_of_range"]
        return size >= need, f"lifts the state's bottom by {size:.1f} % of its range (needs >= {need} %)"
'''
FLOOR_LEVEL = -0.4  # the floor under the lag's state, in the drive's unit (the lag has unit DC gain)


def _floor_class(folder):
    (folder / "floor.py").write_text(FLOOR)
    return h.import_file(folder / "floor.py", "lab_floor").Floor


def _floored_lag(u: np.ndarray) -> np.ndarray:
    """The exact ZOH lag (`helpers.zoh_lag`'s step) held at or above `FLOOR_LEVEL` after every step."""
    a, x, state = np.exp(-1.0 / (RATE * TAU)), np.empty(len(u)), 0.0
    for k, uk in enumerate(u):
        x[k] = state
        state = max(a * state + (1 - a) * uk, FLOOR_LEVEL)
    return x


def test_a_users_floor_is_held_under_its_state_and_its_cut_counts_the_bottom(tmp_path):
    """A limit from below, written by a user: the stack holds the state on it after every step (against
    the lag stepped in numpy with the floor) and measures its cut at the bottom of the state's range,
    which the plug-in's materiality reads (an upper limit's cut alone read 0 % for it)."""
    floor = _floor_class(tmp_path)(floor_level=FLOOR_LEVEL)
    u = _drive(5, 20.0)
    stack = hybrid.EffectStack(hybrid.LTI(1, tau_1=TAU), [floor])
    np.testing.assert_allclose(
        np.asarray(stack.simulate(jnp.asarray(u), 1 / RATE)), _floored_lag(u), atol=1e-3
    )
    free = h.zoh_lag(u, 1 / RATE, TAU)
    lifted = 100 * (FLOOR_LEVEL - np.min(free)) / np.ptp(free)
    cut = stack.derived(jnp.asarray(u), 1 / RATE)["floor"]["cut_percent_of_range"]
    assert lifted > 10 and cut == pytest.approx(lifted, abs=0.2)


def test_the_cli_names_a_users_floor_inside_the_dynamics(tmp_path):
    _floor_class(tmp_path)
    u = _drive(7, 40.0)
    x = _floored_lag(u)
    rng = np.random.default_rng(8)
    w = GAIN * x + OFFSET + 0.005 * np.ptp(GAIN * x) * rng.normal(size=u.size)
    hybrid.Recording.from_arrays(v_in=u, w=w, rate=RATE).save(tmp_path / "lab.csv")
    run = _hybrid(
        tmp_path, "diagnose", "lab.csv", "--physics", "lti:1", "--effects", "floor.py:Floor,saturation",
        "--out", "report", "--quiet",
    )  # fmt: skip
    assert run.returncode == 0, run.stderr[-2000:]
    report = json.loads((tmp_path / "report" / "report.json").read_text())
    assert [c["name"] for c in report["causes"]] == ["floor"], report["verdict"]
    level = report["parameters"]["floor_level"]
    assert level["value"] == pytest.approx(FLOOR_LEVEL, abs=0.02) and level["unit"] == "V", level
    # the fitted floor's cut on the fitted state, against the state's lift in the recording's own lag
    free = h.zoh_lag(u, 1 / RATE, TAU)
    lifted = 100 * (FLOOR_LEVEL - np.min(free)) / np.ptp(free)
    assert report["causes"][0]["derived"]["cut_percent_of_range"] == pytest.approx(lifted, abs=3.0)
