"""Drive generators: sampling, bounds, determinism, shape, bad parameters."""

import numpy as np
import pytest

from hybrid import InputError
from hybrid.data._drive import Drive
from hybrid.data._drives import DRIVES, make_drive
from hybrid.data._paper_drives import chirp, prbs, pulse, sine


def _holds(v):
    """Lengths, in samples, of the runs of equal values in v."""
    edges = np.flatnonzero(np.diff(v) != 0) + 1
    return np.diff(np.concatenate([[0], edges, [len(v)]]))


def _zero_crossings(t, v):
    """Times where v changes sign, by linear interpolation."""
    i = np.flatnonzero(np.sign(v[:-1]) * np.sign(v[1:]) < 0)
    return t[i] - v[i] * (t[i + 1] - t[i]) / (v[i + 1] - v[i])


@pytest.mark.parametrize("name", DRIVES)
def test_sampling_and_metadata(name):
    drive = make_drive(name, duration=10.0, rate=30.0)
    assert isinstance(drive, Drive)
    assert drive.name == name
    assert len(drive) == drive.n == 300
    np.testing.assert_array_equal(drive.t, np.arange(300) / 30.0)
    assert drive.rate == 30.0 and drive.duration == pytest.approx(10.0)
    assert drive.params["duration"] == 10.0 and drive.params["rate"] == 30.0
    assert drive.metadata["name"] == name
    assert not drive.v.flags.writeable
    import json

    json.dumps(drive.metadata)


def test_default_rate_is_the_camera_rate():
    assert len(sine(2.0)) == 60


@pytest.mark.parametrize("name", DRIVES)
def test_amplitude_bounds(name):
    drive = make_drive(name, duration=60.0, rate=30.0, amplitude=1.5)
    assert np.max(np.abs(drive.v)) <= 1.5 + 1e-12
    assert np.max(np.abs(drive.v)) > 1.0


@pytest.mark.parametrize("levels", ["binary", "multilevel"])
def test_prbs_determinism_and_seed(levels):
    first = prbs(60.0, levels=levels, seed=3)
    np.testing.assert_array_equal(first.v, prbs(60.0, levels=levels, seed=3).v)
    assert not np.array_equal(first.v, prbs(60.0, levels=levels, seed=4).v)
    assert first.params["seed"] == 3


def test_prbs_hold_times_within_bounds():
    drive = prbs(600.0, rate=30.0, min_hold=0.5, max_hold=5.0, seed=1)
    holds = _holds(drive.v)[:-1] / 30.0  # the last hold is cut by the duration
    assert holds.min() >= 0.5 - 1e-12 and holds.max() <= 5.0 + 1e-12
    assert holds.min() < 1.0 and holds.max() > 4.0  # spread over the range
    assert set(np.unique(drive.v)) == {-2.0, 2.0}


def test_prbs_multilevel_levels():
    drive = prbs(300.0, levels="multilevel", amplitude=2.0, seed=0)
    levels = np.unique(drive.v)
    assert len(levels) > 20
    assert levels.min() >= -2.0 and levels.max() <= 2.0


def test_sine_values():
    drive = sine(10.0, rate=50.0, amplitude=1.5, frequency=0.5, offset=0.2, phase=0.3)
    np.testing.assert_allclose(drive.v, 0.2 + 1.5 * np.sin(np.pi * drive.t + 0.3), rtol=0, atol=1e-15)


@pytest.mark.parametrize("method", ["linear", "logarithmic"])
def test_chirp_instantaneous_frequency(method):
    f0, f1, duration = 1.0, 5.0, 200.0  # slow sweep: the first and last half periods sit near t = 0 and T
    drive = chirp(duration, rate=100.0, amplitude=1.0, f0=f0, f1=f1, method=method)
    crossings = _zero_crossings(drive.t, drive.v)
    # Half a period between crossings: the local frequency at their midpoint.
    local = 0.5 / np.diff(crossings)
    middle = (crossings[1:] + crossings[:-1]) / 2
    if method == "linear":
        expected = f0 + (f1 - f0) * middle / duration
    else:
        expected = f0 * (f1 / f0) ** (middle / duration)
    np.testing.assert_allclose(local, expected, rtol=2e-3)
    assert local[0] == pytest.approx(f0, rel=0.02)
    assert local[-1] == pytest.approx(f1, rel=0.02)


def test_chirp_default_sweep_and_down_chirp():
    drive = chirp(300.0)
    assert drive.params["f0"] == 0.02 and drive.params["f1"] == 2.0
    assert drive.v[0] == 0.0
    down = chirp(20.0, rate=400.0, f0=5.0, f1=1.0, method="linear")
    crossings = _zero_crossings(down.t, down.v)
    assert 0.5 / np.diff(crossings)[0] > 4.5 and 0.5 / np.diff(crossings)[-1] < 1.5


@pytest.mark.parametrize("duty", [0.25, 0.5, 0.75])
def test_pulse_duty_and_shape(duty):
    drive = pulse(64.0, rate=30.0, amplitude=2.0, period=8.0, duty=duty)
    assert np.mean(drive.v != 0) == pytest.approx(duty)
    period = 240
    first, second = drive.v[:period], drive.v[period : 2 * period]
    on = int(duty * period)
    assert np.all(first[:on] == 2.0) and np.all(first[on:] == 0.0)
    assert np.all(second[:on] == -2.0) and np.all(second[on:] == 0.0)


def test_pulse_unipolar_with_offset():
    drive = pulse(32.0, period=8.0, duty=0.5, offset=0.5, bipolar=False)
    assert set(np.unique(drive.v)) == {0.5, 2.5}


def test_make_drive_passes_seed_and_params():
    drive = make_drive("prbs", 30.0, rate=20.0, seed=7, max_hold=2.0)
    np.testing.assert_array_equal(drive.v, prbs(30.0, rate=20.0, max_hold=2.0, seed=7).v)
    assert make_drive("sine", 5.0, seed=9).params == sine(5.0, seed=9).params


@pytest.mark.parametrize(
    "call, phrase",
    [
        (lambda: make_drive("square", 10.0), "use one of prbs, sine, chirp, pulse"),
        (lambda: make_drive("sine", 10.0, f0=1.0), "no parameter"),
        (lambda: sine(0.0), "duration=0 must be positive"),
        (lambda: sine(-1.0), "must be positive"),
        (lambda: sine(10.0, rate=0.0), "rate=0 must be positive"),
        (lambda: sine(0.01), "at least 2 samples"),
        (lambda: sine(10.0, amplitude=-1.0), "negative"),
        (lambda: sine(10.0, amplitude=float("nan")), "not finite"),
        (lambda: sine(10.0, amplitude="big"), "not a number"),
        (lambda: sine(10.0, frequency=0.0), "must be positive"),
        (lambda: sine(10.0, frequency=15.0), "Nyquist"),
        (lambda: sine(10.0, frequency=20.0), "Nyquist"),
        (lambda: chirp(10.0, f0=-0.1), "must be positive"),
        (lambda: chirp(10.0, f1=16.0), "Nyquist"),
        (lambda: chirp(10.0, method="cubic"), "'logarithmic' or 'linear'"),
        (lambda: pulse(10.0, duty=0.0), "outside (0, 1)"),
        (lambda: pulse(10.0, duty=1.0), "outside (0, 1)"),
        (lambda: pulse(10.0, period=0.0), "must be positive"),
        (lambda: pulse(10.0, period=0.05, duty=0.5), "shorter than one sample"),
        (lambda: prbs(10.0, min_hold=3.0, max_hold=1.0), "exceeds max_hold"),
        (lambda: prbs(10.0, min_hold=0.0), "must be positive"),
        (lambda: prbs(10.0, min_hold=0.01, max_hold=0.02), "no whole number of samples"),
        (lambda: prbs(10.0, levels="ternary"), "'binary' or 'multilevel'"),
        (lambda: prbs(10.0, seed=-1), "non-negative integer"),
        (lambda: prbs(10.0, seed=1.5), "non-negative integer"),
    ],
)
def test_bad_parameters(call, phrase):
    with pytest.raises(InputError) as error:
        call()
    assert phrase in str(error.value)


# --------------------------------------------------------------------------- modulation / repeated sweeps
def test_sine_amplitude_modulation_envelope():
    from hybrid.data._paper_drives import sine

    d = sine(90.0, rate=30.0, amplitude=2.0, frequency=1.0, modulation_depth=0.75, modulation_period=45.0)

    # Envelope a(t) = A (1 − m/2 (1 − cos 2πt/T)): full amplitude at t = 0 and t = T,
    # (1 − m) A at t = T/2. Check peaks over one carrier period around those times.
    def peak(t0):
        sel = (d.t >= t0) & (d.t < t0 + 1.0)
        return np.max(np.abs(d.v[sel]))

    # Tolerance 0.03 V: sampling a 1 Hz peak at 30 Hz misses it by up to
    # 1 − cos(π/30) ≈ 0.55 %, and the envelope moves ≤ 0.5 % within the second.
    assert abs(peak(0.0) - 2.0) < 0.03
    assert abs(peak(22.0) - 0.5) < 0.03
    with pytest.raises(InputError, match="modulation_depth"):
        sine(10.0, modulation_depth=1.5)


def test_chirp_repeated_sweeps_are_continuous_and_periodic_in_frequency():
    from hybrid.data._paper_drives import chirp

    d = chirp(240.0, rate=30.0, f0=0.05, f1=1.0, sweep_period=60.0)
    # Continuity: no jump larger than the steepest slope of the fastest sweep allows.
    max_step = 2.0 * 2 * np.pi * 1.0 / 30.0
    assert np.max(np.abs(np.diff(d.v))) <= max_step * 1.01
    # Each 60 s block holds the same sweep: zero-crossing counts per block agree.
    blocks = d.v.reshape(4, -1)
    crossings = [np.sum(np.diff(np.signbit(b).astype(int)) != 0) for b in blocks]
    assert max(crossings) - min(crossings) <= 2
    with pytest.raises(InputError, match="sweep_period"):
        chirp(10.0, sweep_period=-1.0)


@pytest.mark.parametrize("name", ["sine", "chirp"])
def test_random_half_cycle_amplitudes(name):
    extra = {"modulation": "random"} if name == "sine" else {"sweep_period": 20.0, "f1": 1.0}
    drive = make_drive(name, 120.0, rate=100.0, seed=3, amplitude=2.0, modulation_depth=0.6, **extra)
    again = make_drive(name, 120.0, rate=100.0, seed=3, amplitude=2.0, modulation_depth=0.6, **extra)
    other = make_drive(name, 120.0, rate=100.0, seed=4, amplitude=2.0, modulation_depth=0.6, **extra)
    np.testing.assert_array_equal(drive.v, again.v)
    assert not np.array_equal(drive.v, other.v)
    # Each half cycle (between zero crossings) has its own peak in [(1 - depth) A, A].
    crossings = np.flatnonzero(np.sign(drive.v[:-1]) * np.sign(drive.v[1:]) < 0)
    peaks = np.array(
        [np.max(np.abs(drive.v[a + 1 : b + 1])) for a, b in zip(crossings[:-1], crossings[1:]) if b - a > 20]
    )
    assert peaks.min() >= 0.4 * 2.0 - 1e-9 and peaks.max() <= 2.0 + 1e-12
    assert np.std(peaks) > 0.1  # really random, not a constant envelope
    # Continuous: the amplitude switches only where the sine is zero.
    assert np.max(np.abs(np.diff(drive.v))) < 2.0 * 2 * np.pi * 1.0 / 100.0 * 1.05


@pytest.mark.parametrize(
    "name,param,bad",
    [
        ("staircase", "steps", 1),
        ("staircase", "steps", 2.5),
        ("triangle", "levels", 0),
        ("triangle", "levels", True),
    ],
)
def test_count_parameters_must_be_integers(name, param, bad):
    with pytest.raises(InputError, match=f"{name} drive {param} must be an integer"):
        make_drive(name, 10.0, **{param: bad})


def test_staircase_visits_every_level_from_both_sides():
    v = make_drive("staircase", 64.0, rate=10.0, amplitude=2.0, steps=5, step_time=2.0).v
    levels = np.unique(v)
    np.testing.assert_allclose(levels, np.linspace(-2, 2, 5))
    steps = np.diff(v)[np.diff(v) != 0]
    assert np.all(np.isclose(np.abs(steps), 1.0)) and (steps > 0).any() and (steps < 0).any()
