"""`hybrid diagnose` without a search: one-line errors for bad input, strict JSON, the correlation bound.

The tests of a report written by a full run are in `tests/test_diagnose.py`,
which compiles the search once for every run it makes.
"""

import json
import math

import numpy as np
import pytest

from hybrid.cli import main
from hybrid.discovery._report import jsonable, short_name
from hybrid.discovery._report_figures import correlations
from hybrid.discovery.residual_tests import confidence_bound


def _one_line_error(code, err):
    assert code == 2
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("hybrid: error:"), lines[0]


def test_missing_recording_is_one_line_error(tmp_path, capsys):
    code = main(["diagnose", str(tmp_path / "missing.csv"), "--out", str(tmp_path / "d")])
    _one_line_error(code, capsys.readouterr().err)
    assert not (tmp_path / "d").exists()


def test_recording_with_nan_is_one_line_error(tmp_path, capsys):
    path = tmp_path / "nan.csv"
    rows = ["t,v_in,w"] + [
        f"{i / 30:.6f},{np.sin(i / 5):.6f},{'nan' if i == 40 else f'{np.cos(i / 5):.6f}'}" for i in range(200)
    ]
    path.write_text("\n".join(rows) + "\n")
    code = main(["diagnose", str(path), "--out", str(tmp_path / "d")])
    _one_line_error(code, capsys.readouterr().err)


@pytest.mark.parametrize(
    "option,match",
    [("--max-steps", "--max-steps must be at least 1"), ("--blocks", "blocks must be a whole number")],
)
def test_count_option_below_one_is_one_line_error(option, match, tmp_path, capsys):
    path = tmp_path / "ok.csv"
    rows = ["t,v_in,w"] + [f"{i / 30:.6f},{np.sin(i / 5):.6f},{np.cos(i / 5):.6f}" for i in range(200)]
    path.write_text("\n".join(rows) + "\n")
    code = main(["diagnose", str(path), "--out", str(tmp_path / "d"), option, "0"])
    err = capsys.readouterr().err
    _one_line_error(code, err)
    assert match in err
    assert not (tmp_path / "d").exists()


def test_jsonable_writes_nan_as_null_and_converts_numpy():
    value = {
        "a": float("nan"),
        "b": np.float64(1.5),
        "c": np.array([1.0, np.inf, 2.0]),
        "d": [np.int64(3), -np.inf],
        "e": np.bool_(True),
        "f": {"g": np.float32(0.25), "h": None, "i": "x"},
    }
    text = json.dumps(jsonable(value), allow_nan=False)
    assert json.loads(text) == {
        "a": None,
        "b": 1.5,
        "c": [1.0, None, 2.0],
        "d": [3, None],
        "e": True,
        "f": {"g": 0.25, "h": None, "i": "x"},
    }


def test_correlation_figure_bound_is_the_99_percent_bound():
    rng = np.random.default_rng(0)
    e, v = rng.normal(size=777), rng.normal(size=777)
    c = correlations(e, v)
    assert c["bound"] == confidence_bound(777)
    assert c["bound"] == pytest.approx(2.5758293035489 / math.sqrt(777), rel=1e-12)
    assert c["acf_lags"][0] == 1 and c["acf_lags"][-1] == 50 and len(c["acf"]) == 50
    assert c["ccf_lags"][0] == -50 and c["ccf_lags"][-1] == 50


def test_a_parameter_the_recording_does_not_pin_says_so_never_plus_minus_inf():
    from hybrid.discovery._report import plus_minus

    pinned = {"value": 0.5, "std_error": 0.01, "unit": "1/V", "pinned": True}
    assert plus_minus(pinned) == "0.5 ± 0.01 1/V"
    told = {
        "value": 0.084,
        "std_error": float("inf"),
        "unit": "1/V",
        "pinned": False,
        "not_pinned": "the signal it acts on never goes negative",
    }
    text = plus_minus(told)
    assert (
        "inf" not in text
        and "not pinned by this recording: the signal it acts on never goes negative" in text
    )
    # A report written before `pinned` existed (schema 1) still reads right.
    assert "not pinned" in plus_minus({"value": 0.084, "std_error": float("inf"), "unit": "1/V"})
    assert "larger than its value" in plus_minus({"value": 0.01, "std_error": 0.5, "unit": "s"})


def test_a_fixed_parameter_keeps_its_unit_in_the_table():
    from hybrid.discovery._report import parameter_rows

    d = {
        "settings": {"frozen": ["power", "xi_h"]},
        "parameters": {
            "power": {"value": 10.0, "unit": "W/V"},  # a user's heater: the row read "10 (fixed)"
            "xi_h": {"value": 1.0, "unit": "1"},
            "gain": {"value": 2.0, "std_error": 0.1, "unit": "mm/V", "pinned": True},
        },
    }
    assert parameter_rows(d) == [
        "| power | 10 W/V (fixed) |",
        "| xi_h | 1 (fixed) |",
        "| gain | 2 ± 0.1 mm/V |",
    ]


def test_not_pinned_names_the_branch_a_one_sided_signal_never_visits():
    import numpy as np

    import hybrid
    from hybrid.discovery._diagnosis import ParameterUncertainty
    from hybrid.discovery._evidence import not_pinned

    stack = hybrid.EffectStack(hybrid.LTI(1), ("saturation",)).replace(
        saturation_pos_curvature=0.3, saturation_neg_curvature=0.084
    )
    model = hybrid.make_model("physics", simulation=stack)
    series = hybrid.core.series_from_recording(
        hybrid.Recording.from_arrays(v_in=np.abs(np.sin(np.arange(200) * 0.1)), w=np.zeros(200), rate=10.0),
        (0.6, 0.1, 0.3),
        ("train", "validation", "test"),
        1,
    )
    u = {
        "saturation_pos_curvature": ParameterUncertainty(std_error=0.01, unit="1/V", inflation=1.0),
        "saturation_neg_curvature": ParameterUncertainty(std_error=float("inf"), unit="1/V", inflation=1.0),
    }
    reasons = not_pinned(u, model, [series])
    assert reasons == {"saturation_neg_curvature": "the signal it acts on never goes negative"}

    # a value at a bound of its two-sided range: the bound sets it (the tanks' frame lag at 1 sample)
    timed = hybrid.EffectStack(hybrid.LTI(1), ("saturation", hybrid.FrameTiming())).replace(frame_lag=0.9998)
    u["frame_lag"] = ParameterUncertainty(std_error=float("inf"), unit="samples", inflation=1.0)
    u["saturation_pos_curvature"] = ParameterUncertainty(std_error=0.5, unit="1/V", inflation=1.0)
    reasons = not_pinned(u, hybrid.make_model("physics", simulation=timed), [series])
    assert reasons["frame_lag"].startswith("it sits at its upper bound (1 samples): the fit pushed it there")
    assert (
        reasons["saturation_pos_curvature"] == "its standard error (0.5) is larger than its value"
    )  # 0.3: no bound


def test_no_report_key_names_a_unit_that_follows_the_signal():
    """Schema 3: an effect's unit follows its signal, so its keys name none (the renames are listed)."""
    import re

    import hybrid
    from hybrid.discovery import RENAMED_IN_SCHEMA_3, REPORT_SCHEMA

    assert REPORT_SCHEMA == "hybrid-report/4"
    volt = re.compile(r"(^|_)(per_)?(v|mv|kv|mm|m)$")  # a name ending in a unit of a signal
    outside = tuple(n for n, cls in hybrid.EFFECTS.items() if cls.place != "inside")
    stack = hybrid.EffectStack(hybrid.LTI(1), outside)
    s = np.sin(np.linspace(0.0, 6.0, 50))
    keys = {k for cls in hybrid.EFFECTS.values() for k in cls.constraints}
    for effect in stack.effects:  # a saturation's levels are derived only where reached: their units say them
        keys |= set(effect.derived(s, 0.1)) | set(effect.derived_units)
    offenders = sorted(k for k in keys if volt.search(k))
    assert not offenders, offenders
    assert set(RENAMED_IN_SCHEMA_3.values()) <= keys  # every new name is a key an effect writes
    assert not set(RENAMED_IN_SCHEMA_3) & keys  # and no old one is left


def _verdict_of(
    final_over_floor,
    causes=(),
    ambiguous=(),
    independence=None,
    uncertainties=None,
    floor=0.01,
    baseline=0.5,
    candidates=(),
):
    """`verdict` of a diagnosis whose final held-out MSE is `final_over_floor` × a floor of `floor`, w's
    variance 1 and the baseline's held-out MSE `baseline`.

    `independence`: the final model's held-out `drive_independence` test (None: not tested);
    `uncertainties`: its parameters' `ParameterUncertainty` by name; `candidates`: the last step's."""
    from types import SimpleNamespace

    from hybrid.discovery._diagnosis import DiagnoseSettings
    from hybrid.discovery._verdict import verdict

    w = np.array([-1.0, 1.0])  # var 1: NMSE is the MSE
    fit = lambda nmse: SimpleNamespace(heldout=SimpleNamespace(nmse=nmse))
    return verdict(
        SimpleNamespace(
            causes=list(causes),
            heldout=SimpleNamespace(w=w),
            baseline=fit(baseline),
            extended=fit(floor * final_over_floor),
            noise_floor=SimpleNamespace(variance=floor),
            unexplained=None,
            ambiguous=list(ambiguous),
            dropped=[],
            settings=DiagnoseSettings(),
            gain=baseline / (floor * final_over_floor),
            steps=[SimpleNamespace(candidates=list(candidates))],
            evidence={"extended": {"drive_independence": independence}},
            uncertainties=dict(uncertainties or {}),
        )
    )


def test_the_verdict_says_as_good_as_the_data_allow_only_near_the_floor():
    """At 1.7× the floor (a user's quadratic drag the library lacks) it said 'as good as the data allow'."""
    assert _verdict_of(1.1).endswith("1.1× the measurement noise floor, as good as the data allow.")
    near = _verdict_of(1.7)
    assert "1.7× the measurement noise floor, under the 2× above which the rest is called unexplained" in near
    assert "as good as the data allow" not in near and "an effect outside the library may still" in near
    named = _verdict_of(1.0, [{"name": "back_relaxation"}, {"name": "slew_limit"}])
    assert named.startswith("back_relaxation and slew_limit explain 100%")  # as report.json spells them
    assert named.endswith("; what remains is measurement noise.")
    # a new user's heated block: baseline_drift named, a heat loss left at 1.8× the floor, and the verdict
    # called what remained measurement noise
    short = _verdict_of(1.8, [{"name": "baseline_drift"}])
    assert "measurement noise." not in short and "what remains is 1.8× the measurement noise floor" in short
    assert "too small for the rules on this recording" in short
    # above 2× the floor's estimate but under 2× its upper bound (estimate + 2 SE): not "under the 2×"
    over = _verdict_of(2.1)
    assert "2.1× the measurement noise floor, yet under 2× the floor's upper bound (its estimate + 2 " in over
    # a new user's rising staircase, its sensor drifting: "No effect is needed" led the report while the
    # last step was open between nothing more and baseline_drift; the headline now says it is open
    entry = {"step": 1, "named": "none", "open": True, "rivals": [{"name": "baseline_drift"}]}
    asked = _verdict_of(1.1, ambiguous=[entry])
    assert "No effect is needed" not in asked and "as good as the data allow" not in asked
    assert "whether baseline_drift is missing is open on this recording" in asked and "hybrid design" in asked
    named = _verdict_of(1.0, [{"name": "saturation"}], ambiguous=[entry])
    assert "measurement noise." not in named and "whether baseline_drift is also missing is open" in named
    # a rival of a named cause (not an open step) leaves the all-clear as it was
    rival = {"step": 1, "named": "saturation", "rivals": [{"name": "drift"}]}
    assert _verdict_of(1.0, [{"name": "saturation"}], ambiguous=[rival]).endswith(
        "what remains is measurement noise."
    )


def test_an_all_clear_under_a_large_noise_says_how_large_an_effect_it_can_hide():
    """A probe's saturation under a noise as large as the response (floor 53 % of var w): 'No effect is
    needed … as good as the data allow', though it fitted the training part far better (ΔBIC −66) and no
    cause could gain 1.5× held out there. The all-clear now says the size the noise hides: an effect adding
    e to the MSE gains at most 1 + e/floor, so e < 0.5·floor (an rms under √(0.5·0.5) = 50 % of w's)."""
    from types import SimpleNamespace

    saturation = SimpleNamespace(name="saturation", material=True, gain=1.04, delta_bic=-66.0)
    noisy = _verdict_of(1.0, floor=0.5, baseline=0.52, candidates=[saturation])
    assert noisy.startswith(
        "No effect is needed: the simulation's held-out error is 1× the measurement noise"
    )
    assert (
        "But the noise is 50% of w's variance: an effect whose error is under 0.5× the noise's variance (an rms "
        in noisy
    )
    assert "under 50% of w's) cannot gain the 1.5× a cause needs here" in noisy
    assert "(saturation fits the training part better, ΔBIC −66, and gains 1.04× held out)" in noisy
    # a candidate the BIC does not favour is not quoted; a cause named under such a noise gets the clause too
    weak = SimpleNamespace(name="saturation", material=True, gain=1.04, delta_bic=-3.0)
    assert "fits the training part" not in _verdict_of(1.0, floor=0.5, baseline=0.52, candidates=[weak])
    named = _verdict_of(1.0, [{"name": "saturation"}], floor=0.2, baseline=0.6)
    assert "what remains is measurement noise. But the noise is 20% of w's variance" in named
    assert "an rms under 32% of w's" in named  # √(0.5 · 0.2)
    # a clean record (floor 1 % of var w) keeps its plain all-clear
    assert _verdict_of(1.0).endswith("as good as the data allow.")


def test_an_output_that_does_not_follow_the_drive_is_not_an_all_clear():
    """A probe's w of white noise unrelated to the drive read 'No effect is needed: … 1× the measurement
    noise floor, as good as the data allow' (held-out NMSE 1.01, Fitting −52 %, the floor all of var w)."""
    said = _verdict_of(1.0, floor=1.0, baseline=1.01)
    assert said.startswith("Nothing can be named from this recording: w barely follows the drive.")
    assert (
        "The simulation explains 0% of w's held-out variance" in said
        and "which is 100% of w's variance" in said
    )
    assert "No effect is needed" not in said and "check that the output is the response to this drive" in said
    # a simulation that explains a fifth of w or more, under a large noise, is not told so
    assert _verdict_of(1.0, floor=0.7, baseline=0.72).startswith("No effect is needed")


def test_the_verdict_says_when_a_remainder_near_the_floor_still_follows_the_drive():
    """A remainder the size of the noise that still correlates with the drive is no all-clear."""
    follows = {"statistic": 85.2, "lags": 31, "order": 10, "p_value": 6.3e-7}
    said = "Yet it still follows the drive (the held-out residual against the drive before it, both prewhitened: "
    said += "χ²(31) = 85, p = 6e-07): part of the response that the drive causes is left, not noise alone."
    none = _verdict_of(1.1, independence=follows)
    assert "No effect is needed" not in none and "as good as the data allow" not in none
    assert none.startswith("No effect of the library is needed by the search's rules") and none.endswith(said)
    named = _verdict_of(1.0, [{"name": "saturation"}], independence=follows)
    assert "what remains is measurement noise" not in named
    assert named.endswith("what remains is 1× the measurement noise floor in size. " + said)
    near = _verdict_of(1.7, [{"name": "saturation"}], independence=follows)
    assert "under the 2× above which it is called unexplained" in near and near.endswith(said)
    # a parameter the fit left short of its training optimum is named as a reading of it (a plug-in
    # pendulum's frame lag kept at its start: at its optimum the residual no longer followed the drive)
    from hybrid.discovery._diagnosis import ParameterUncertainty

    held = ParameterUncertainty(0.044, "samples", 1.0, to_optimum=-0.211)
    at = ParameterUncertainty(0.0029, "1", 1.0, to_optimum=0.0045)  # 1.6 standard errors: not said
    short = _verdict_of(1.1, independence=follows, uncertainties={"frame_lag": held, "gain": at})
    assert short.endswith(
        said + " The fit stopped short of the training part's optimum in frame_lag (4.8 standard errors), "
        "which alone can leave such a part (report.md's parameters give that optimum)."
    )
    assert _verdict_of(1.1, uncertainties={"frame_lag": held}) == _verdict_of(1.1)  # no dependence: no word
    # a residual the test finds independent of the drive, or one it could not test, changes nothing
    for independent in ({**follows, "p_value": 0.02}, None):
        assert _verdict_of(1.1, independence=independent) == _verdict_of(1.1)
        assert _verdict_of(1.0, [{"name": "saturation"}], independence=independent).endswith(
            "what remains is measurement noise."
        )


def test_the_verdict_says_when_the_names_rest_on_a_simulation_fitted_outside_its_plausible_range():
    """A new user's `lti:2` with a 45 s wander: "resonance and stiffness explain 90 %" led the report while the
    plant's own mode had taken the wander (ζ 2.4e-6, below lti's plausible 1e-3) and the resonance the plant's."""
    from types import SimpleNamespace

    import hybrid
    from hybrid.discovery._diagnosis import DiagnoseSettings
    from hybrid.discovery._verdict import verdict

    w = np.array([-1.0, 1.0])
    fit = lambda nmse: SimpleNamespace(heldout=SimpleNamespace(nmse=nmse))

    def said(causes, zeta, frozen=None):
        plant = hybrid.LTI(2).replace(f_1=0.022, zeta_1=zeta)
        return verdict(
            SimpleNamespace(
                causes=causes,
                heldout=SimpleNamespace(w=w),
                baseline=fit(0.5),
                extended=fit(0.01),
                noise_floor=SimpleNamespace(variance=0.01),
                unexplained=None,
                ambiguous=[],
                dropped=[],
                settings=DiagnoseSettings(frozen=frozen),
                gain=50.0,
                evidence={},
                models={"extended": SimpleNamespace(simulation=plant)},
            )
        )

    named = said([{"name": "resonance"}], 2.4e-6)
    assert named.startswith("resonance explains 100%")
    assert (
        "; but the simulation was fitted outside its plausible range (zeta_1 = 2.4e-06; see the warnings)"
        in named
    )
    assert named.endswith(
        "a named cause may be standing in for what the simulation should do, and the simulation for a cause."
    )
    alone = said([], 2.4e-6)
    assert alone.startswith("No effect is needed") and alone.endswith(
        "it may have taken up what a missing effect does."
    )
    # within the range, or held there by the user (frozen), the sentence is as it was
    assert said([{"name": "resonance"}], 0.3).endswith("what remains is measurement noise.")
    assert said([{"name": "resonance"}], 2.4e-6, frozen=("zeta_1",)).endswith(
        "what remains is measurement noise."
    )


@pytest.mark.parametrize(
    "name, short",
    [
        # a column named quantity/unit (ISO 80000) once cut the title to "µm)"
        ("units.csv (u [V] -> Displacement/µm)", "units.csv (u [V] -> Displacement/µm)"),
        ("/lab/day 2/units.csv (u [V] -> Displacement/µm)", "units.csv (u [V] -> Displacement/µm)"),
        ("/lab/run (2).csv", "run (2).csv"),
        ("lab/run.csv", "run.csv"),
        ("synthetic strip", "synthetic strip"),
    ],
)
def test_the_reports_title_names_each_recording_without_its_folders(name, short):
    assert short_name(name) == short


def test_the_closest_candidate_is_refused_for_the_rule_it_failed():
    """A new user's pendulum (a cogging torque): "the closest, drive_saturation, gains 2.18× held out, under
    the 1.5× asked" — 2.18 is not under 1.5; the rule it failed was the effect-free fit as good on training."""
    from types import SimpleNamespace

    from hybrid.discovery._verdict import refusal

    bar = "an effect-free fit as good on training reaches held-out NMSE 0.0121: gain over it 0.75 < 1.5"
    strong = SimpleNamespace(gain=2.18, reasons=[bar])
    assert refusal(strong, 1.5) == f"gains 2.18× held out, but {bar}"
    weak = SimpleNamespace(gain=1.37, reasons=["held-out gain 1.37 < 1.5", "ΔBIC -3.0 > −10.0"])
    assert refusal(weak, 1.5) == "gains 1.37× held out, under the 1.5× asked"


def test_an_output_side_causes_unit_is_said_where_it_is_not_ws():
    """A probe's baseline drift on a millimetre sensor read "2.226 V/min" beside an offset in mm: `lti:N`'s
    output is in the drive's unit, and nothing said why."""
    from hybrid.discovery._report import _output_unit_note

    d = {
        "effects": [
            {"name": "baseline_drift", "place": "output"},
            {"name": "drive_dead_zone", "place": "drive"},
        ],
        "causes": [{"name": "drive_dead_zone"}, {"name": "baseline_drift"}],
        "parameters": {"gain": {"value": 0.994, "unit": "mm/V"}},
        "units": {"w": "mm", "v_in": "V"},
    }
    (said,) = [line for line in _output_unit_note(d) if line]
    assert said.startswith("baseline_drift acts on the simulation's output before the readout")
    assert "its parameters are in the simulation's unit, V; × the gain (0.994 mm/V) gives w's, mm." in said
    # a drive-side cause alone, or a simulation already in w's unit: nothing to say
    assert _output_unit_note({**d, "causes": [{"name": "drive_dead_zone"}]}) == []
    assert _output_unit_note({**d, "parameters": {"gain": {"value": 1.0, "unit": "mm/mm"}}}) == []


def test_the_all_clear_names_the_bound_it_is_under():
    """report.md said "within 2× the floor: nothing is left unexplained" beside a verdict of 2.1× (a probe):
    the rule counts the floor at its estimate + 2 standard errors, and the sentence now says so."""
    from hybrid.discovery._report import noise_section

    floor = {"std": 0.1, "variance": 0.01, "std_error": 0.001, "fraction_of_variance": 0.02, "method": "m"}
    d = {
        "noise_floor": floor,
        "unexplained": None,
        "settings": {"unexplained_ratio": 2.0},
        "units": {"w": "mm"},
    }
    text = "\n".join(noise_section(d))
    assert "within 2× the floor's upper bound (its estimate + 2 standard errors): nothing is left" in text


def test_a_remainder_near_the_unexplained_ratio_is_not_rounded_onto_it():
    """A probe's remainder at 1.996× the floor read "2× the measurement noise floor, under the 2× above
    which it is called unexplained": the ratio is given to the digits that keep it on its side."""
    from hybrid.discovery._verdict import _beside

    assert _beside(1.996, 2.0) == "1.996" and _beside(2.004, 2.0) == "2.004"
    assert _beside(1.5, 2.0) == "1.5" and _beside(2.7, 2.0) == "2.7"  # two digits where they do
    for ratio in np.linspace(1.9, 2.1, 41):
        assert (float(_beside(ratio, 2.0)) < 2.0) == (ratio < 2.0)
