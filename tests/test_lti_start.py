"""`lti:N` starts at the recording's own time scale, at any rate from 0.25 Hz to 100 kHz.

Records are made by scipy alone (exact ZOH discretisation of the continuous
system, `scipy.signal.cont2discrete`), the drive band-limited noise. The
frequency read off the data is checked against the system's own (a resonance,
a first-order corner), and the real command line fits ``--physics lti:2`` on a
100 kHz and a 0.25 Hz file to the true mode, which it did not do from the
defaults centred on 1 s (`benchmarks/long_record.py`: f_1 = 0.48 Hz for 800 Hz).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import scipy.signal

import hybrid
from hybrid.cli import main
from hybrid.physics._lti_start import lti_for_recordings, response_frequency


def record(num, den, rate, n=8000, seed=0, noise=0.01):
    """(u, y): the continuous system num/den driven by noise band-limited to rate/8, held over each sample."""
    rng = np.random.default_rng(seed)
    b, a = scipy.signal.butter(4, 0.25)  # a quarter of Nyquist
    u = scipy.signal.lfilter(b, a, rng.normal(size=n))
    u /= np.std(u)
    ad, bd, cd, dd, _ = scipy.signal.cont2discrete(scipy.signal.tf2ss(num, den), 1.0 / rate, method="zoh")
    y = scipy.signal.dlsim((ad, bd, cd, dd, 1.0 / rate), u)[1][:, 0]
    return u, y + noise * np.std(y) * rng.normal(size=n)


@pytest.mark.parametrize("rate, f0", [(100_000.0, 800.0), (610.35, 60.0), (0.25, 0.01)])
def test_a_resonance_is_read_at_its_frequency(rate, f0):
    w0, zeta = 2 * math.pi * f0, 0.1
    u, y = record([w0**2], [1.0, 2 * zeta * w0, w0**2], rate)
    assert response_frequency(u, y, rate) == pytest.approx(f0, rel=0.1)


@pytest.mark.parametrize("rate, tau", [(1000.0, 0.02), (0.25, 200.0)])
def test_a_first_order_corner_is_read_at_one_over_two_pi_tau(rate, tau):
    u, y = record([1.0], [tau, 1.0], rate)
    assert response_frequency(u, y, rate) == pytest.approx(1 / (2 * math.pi * tau), rel=0.3)


def test_the_start_is_centred_and_given_values_win():
    rate, f0 = 100_000.0, 800.0
    w0 = 2 * math.pi * f0
    u, y = record([w0**2], [1.0, 0.2 * w0, w0**2], rate)
    rec = hybrid.Recording(t=np.arange(len(u)) / rate, v_in=u, w=y)
    assert float(lti_for_recordings(2, [rec]).parameters()["f_1"]) == pytest.approx(f0, rel=0.1)
    assert float(lti_for_recordings(2, [rec], f_1=5.0).parameters()["f_1"]) == pytest.approx(5.0)
    four = lti_for_recordings(4, [rec]).parameters()  # two sections, half a decade either side of the centre
    assert math.sqrt(float(four["f_1"]) * float(four["f_2"])) == pytest.approx(f0, rel=0.1)
    # `resolve_physics` takes one Recording as `fit` and `diagnose` do (it raised a TypeError).
    one = hybrid.resolve_physics("lti:2", rec).parameters()["f_1"]
    assert float(one) == float(hybrid.resolve_physics("lti:2", [rec]).parameters()["f_1"])
    assert float(one) == pytest.approx(f0, rel=0.1)
    with pytest.raises(hybrid.InputError, match="resolve_physics needs Recording objects"):
        hybrid.resolve_physics("lti:2", {"v_in": u})


def test_w_where_it_was_not_measured_does_not_move_the_start():
    """Samples of quality 0 (a tracker's held frames): the fits leave them out, and the start the fits begin
    from reads them off a line between their measured neighbours. A verifier set them to -50 (w ~ ±1): the
    fitted lti:2 moved, through its start alone; here the start read 6.4 Hz for 0.7."""
    rate, f0 = 30.0, 0.7
    w0 = 2 * math.pi * f0
    u, y = record([w0**2], [1.0, 0.2 * w0, w0**2], rate, n=3000)
    quality = np.ones(len(u))
    for a in range(100, 2900, 150):  # a run of 6 held frames every 5 s
        quality[a : a + 6] = 0.0
    held, wild = y.copy(), y.copy()
    for a in range(100, 2900, 150):
        held[a : a + 6] = y[a - 1]
        wild[a : a + 6] = -50.0
    t = np.arange(len(u)) / rate
    starts = [
        lti_for_recordings(2, [hybrid.Recording(t=t, v_in=u, w=w, extra={"quality": quality})]).parameters()
        for w in (held, wild)
    ]
    assert {k: float(v) for k, v in starts[0].items()} == {k: float(v) for k, v in starts[1].items()}
    assert float(starts[0]["f_1"]) == pytest.approx(f0, rel=0.15)
    # without the column every sample counts: the wild values move it
    bare = lti_for_recordings(2, [hybrid.Recording(t=t, v_in=u, w=wild)]).parameters()
    assert float(bare["f_1"]) != float(starts[1]["f_1"])


@pytest.mark.parametrize("rate, f0", [(100_000.0, 800.0), (0.25, 0.01)])
def test_the_cli_fits_lti_2_at_any_rate(rate, f0, tmp_path, capsys):
    w0 = 2 * math.pi * f0
    u, y = record([w0**2], [1.0, 0.2 * w0, w0**2], rate, n=6000)
    path = tmp_path / "lab.csv"
    path.write_text("u_cmd,y_meas\n" + "".join(f"{a:.9g},{b:.9g}\n" for a, b in zip(u, y)))
    report = tmp_path / "fit.json"
    code = main(
        [
            str(a)
            for a in [
                "fit",
                path,
                "--columns",
                "input=u_cmd,output=y_meas",
                "--rate",
                rate,
                "--physics",
                "lti:2",
                "--model",
                "physics",
                "--max-steps",
                "100",
                "--quiet",
                "--out",
                tmp_path / "m.eqx",
                "--json",
                report,
            ]
        ]
    )
    assert code == 0, capsys.readouterr().err
    fitted = json.loads(report.read_text())
    assert fitted["parameters"]["f_1"] == pytest.approx(f0, rel=0.01)
    assert fitted["parameters"]["zeta_1"] == pytest.approx(0.1, rel=0.05)


def test_a_frequency_above_the_nyquist_frequency_is_warned_about_as_its_alias():
    """A 1.2 Hz, ζ 0.4 mode sampled at 30 Hz has the discrete poles of a 28.9 Hz, ζ 0.0169 one (a fit of
    `lti:2` with a sensor's lag landed there): the warning names the alias the samples show."""
    from hybrid.core._result import aliased

    rate, f, zeta = 30.0, 28.9236, 0.0169

    def poles(f, zeta):
        w = 2 * np.pi * f
        a = np.array([[0.0, 1.0], [-w * w, -2 * zeta * w]])
        ad, *_ = scipy.signal.cont2discrete(
            (a, np.array([[0.0], [w * w]]), np.eye(2), np.zeros((2, 1))), 1 / rate
        )
        return np.sort_complex(np.linalg.eigvals(ad))

    model = hybrid.make_model("physics", simulation=hybrid.LTI(order=2, f_1=f, zeta_1=zeta))
    (said,) = aliased(model, (), rate)
    alias = float(said.split("alias near ")[1].split(" Hz")[0])
    assert alias == pytest.approx(rate - f, rel=1e-3) and "f_1 = 28.9236 Hz" in said
    # the alias with the same decay per sample (σ = ζω kept) has the same discrete poles (scipy's ZOH)
    sigma = zeta * 2 * np.pi * f
    w_d = 2 * np.pi * f * math.sqrt(1 - zeta**2) - 2 * np.pi * rate
    w_alias = math.hypot(sigma, w_d)
    np.testing.assert_allclose(poles(f, zeta), poles(w_alias / (2 * np.pi), sigma / w_alias), atol=1e-12)
    # that equivalent mode is the plant's own (1.2 Hz, ζ 0.4) within the digits given, near the fold of f
    assert w_alias / (2 * np.pi) == pytest.approx(1.2, rel=0.02) and sigma / w_alias == pytest.approx(
        0.4, rel=0.05
    )
    assert w_alias / (2 * np.pi) == pytest.approx(alias, rel=0.15)
    # below the Nyquist frequency, frozen, or no rate: nothing said
    below = hybrid.make_model("physics", simulation=hybrid.LTI(order=2, f_1=1.2, zeta_1=0.4))
    assert (
        aliased(below, (), rate) == []
        and aliased(model, ("f_1",), rate) == []
        and aliased(model, (), None) == []
    )


def test_a_time_constant_within_one_sample_is_warned_about():
    """`lti:1` on a camera's 30 Hz record of a fast strip fitted τ = 2.3 ms, its section a gain: the
    samples cannot pin a time under a tenth of their step, and the fit now says so (and why)."""
    from hybrid.core._result import sub_sample

    rate = 30.0
    fast = hybrid.make_model("physics", simulation=hybrid.LTI(order=1, tau_1=2.3e-3))
    (said,) = sub_sample(fast, (), rate)
    assert "tau_1 = 0.0023 s is under a tenth of the sample step (0.0333 s at 30 Hz)" in said
    # the samples alike: a lag of 2.3 ms and of 0.23 ms move a held step by the same share within a step
    for tau in (2.3e-3, 2.3e-4):
        assert math.exp(-1 / (rate * tau)) < 1e-6
    slow = hybrid.make_model("physics", simulation=hybrid.LTI(order=1, tau_1=0.01))  # 0.3 of a step
    assert sub_sample(slow, (), rate) == [] and sub_sample(fast, ("tau_1",), rate) == []
    assert sub_sample(fast, (), None) == []
