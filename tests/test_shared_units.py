"""Recordings fitted together in different units of one quantity: converted to the first's, or refused.

A lab's two files of one strip, one logged in mm and one in µm (or a drive in mV beside V),
were fitted as numbers on two scales: a gain of 1000 mm/V and a noise floor in the hundreds of σ,
with no error. `in_shared_units` scales each to the first recording's units where an SI prefix
relates them (the reference: the same recording written in the first's unit) and refuses what
no prefix relates (counts beside mm).
"""

from __future__ import annotations

import dataclasses
import json

import helpers as h
import numpy as np
import pytest
import scipy.signal

import hybrid
from hybrid import InputError
from hybrid.data._header_units import prefix_factor
from hybrid.data._recording import in_shared_units


@pytest.mark.parametrize(
    "unit, to, factor",
    [
        ("µm", "mm", 1e-3),
        ("um", "mm", 1e-3),
        ("μm", "mm", 1e-3),  # Greek mu
        ("mm", "m", 1e-3),
        ("m", "mm", 1e3),
        ("mV", "V", 1e-3),
        ("kPa", "Pa", 1e3),
        ("mm", "mm", 1.0),
        ("counts", "mm", None),
        ("mm", "V", None),
        ("mm/s", "m/s", None),  # a compound unit: not converted by a prefix
    ],
)
def test_a_prefix_relates_two_units_of_one_symbol_and_nothing_else(unit, to, factor):
    got = prefix_factor(unit, to)
    assert got == (None if factor is None else pytest.approx(factor, rel=1e-15))


def _lag(seed: int, scale: float = 1.0, units=None, rate: float = 30.0, n: int = 1800):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate
    v = np.repeat(rng.uniform(-1, 1, n // 30 + 1), 30)[:n]
    y = scipy.signal.lsim(scipy.signal.lti([2.0], [0.3, 1.0]), v, t)[1]
    w = y + 0.01 * rng.normal(size=n)
    metadata = {"units": {"t": "s", "v_in": "V", "w": "mm", **(units or {})}}
    return hybrid.Recording(
        t, v * (1000.0 if metadata["units"]["v_in"] == "mV" else 1.0), w * scale, {}, metadata
    )


def test_recordings_in_um_and_mv_are_put_in_the_firsts_units_with_a_note():
    first, second = _lag(0), _lag(1, 1000.0, {"w": "µm", "v_in": "mV"})
    same, converted = in_shared_units([first, second], "fit")
    assert same is first
    reference = _lag(1)
    np.testing.assert_allclose(converted.w, reference.w, rtol=1e-14)
    np.testing.assert_allclose(converted.v_in, reference.v_in, rtol=1e-14)
    assert converted.metadata["units"] == {"t": "s", "v_in": "V", "w": "mm"}
    assert any("from µm to mm (×0.001)" in n and "from mV to V" in n for n in converted.notes)
    assert in_shared_units([first, reference], "fit")[1] is reference  # one unit already: untouched


@pytest.mark.parametrize("role, factor", [("v_in", 1000.0), ("w", 1e-3), ("v_in", 10.0), ("w", 1e6)])
def test_a_recording_a_power_of_1000_apart_in_one_unit_gets_a_note(role, factor):
    """A probe's second recording of one motor had its drive logged in mV, no unit said: 0.5–5 beside
    500–5000, both read as V, and the diagnosis blamed a dead zone. One a power of 1000 apart gets a
    note that says so; one 10× apart (a smaller test) does not."""
    first, second = _lag(0), _lag(1)
    second = dataclasses.replace(second, **{role: getattr(second, role) * factor})
    notes = in_shared_units([first, second], "fit")[1].notes
    said = [n for n in notes if "the size of that in" in n]
    assert bool(said) == (factor != 10.0), notes
    if said:
        (note,) = said
        power = round(np.log10(factor))
        assert f"(near 10^{power}, the step between units)" in note and f"--units {role}=" in note
    assert in_shared_units([first, _lag(2)], "fit")[1].notes == ()  # one scale: nothing said


def test_units_no_prefix_relates_are_refused_with_one_line_naming_both():
    with pytest.raises(InputError, match=r"gives the output \(w\) in counts, but .* gives it in mm") as error:
        hybrid.fit(
            hybrid.make_model("physics", simulation=hybrid.LTI(1)),
            [_lag(0), _lag(1, units={"w": "counts"})],
            solver=hybrid.LevenbergMarquardt(max_steps=1),
            progress=False,
        )
    assert "\n" not in str(error.value)


def test_the_command_line_fits_mm_and_um_files_as_one_scale(tmp_path):
    _lag(0).save(tmp_path / "mm.csv")
    _lag(1, 1000.0, {"w": "µm"}).save(tmp_path / "um.csv")
    _lag(1).save(tmp_path / "mm_too.csv")
    _lag(2, 1000.0, {"w": "µm"}).save(tmp_path / "um_test.csv")  # scored in the fitted mm
    _lag(2).save(tmp_path / "mm_test.csv")
    fits = {}
    for name, files in (("mixed", ["mm.csv", "um.csv"]), ("reference", ["mm.csv", "mm_too.csv"])):
        done = h.run_hybrid(
            tmp_path,
            "fit",
            *files,
            "--model",
            "physics",
            "--physics",
            "lti:1",
            "--quiet",
            "--json",
            f"{name}.json",
            "--out",
            f"{name}.eqx",
            "--test",
            "um_test.csv" if name == "mixed" else "mm_test.csv",
        )
        assert done.returncode == 0, done.stderr[-2000:]
        fits[name] = json.loads((tmp_path / f"{name}.json").read_text())
        if name == "mixed":
            assert "from µm to mm (×0.001)" in done.stderr
    mixed, reference = (fits[k]["parameters"] for k in ("mixed", "reference"))
    for key in reference:
        assert mixed[key] == pytest.approx(reference[key], rel=1e-6, abs=1e-9), key
    scored = [fits[k]["test"][0] for k in ("mixed", "reference")]
    assert scored[0]["unit"] == "mm" and scored[0]["rmse"] == pytest.approx(scored[1]["rmse"], rel=1e-6)
    assert reference["tau_1"] == pytest.approx(0.3, rel=0.02)  # the lag as simulated (scipy)


def test_diagnose_in_python_reports_what_putting_its_recordings_in_one_unit_said():
    """The command line prints each recording's notes as it loads them; `hybrid.diagnose` called with
    recordings put them in one unit itself and said nothing: a conversion (mV to V) and a drive a power of
    1000 apart in one unit (a probe's mV logged as V) are in its warnings."""
    unlabelled = _lag(2)
    unlabelled = dataclasses.replace(unlabelled, v_in=unlabelled.v_in * 1000.0)  # mV, read as V
    found = hybrid.diagnose(
        [_lag(0), _lag(1, units={"v_in": "mV"}), unlabelled], simulation=hybrid.LTI(1), effects=["lag"]
    )
    assert any("from mV to V (×0.001)" in w for w in found.warnings), found.warnings
    assert any("(near 10^3, the step between units)" in w for w in found.warnings), found.warnings
