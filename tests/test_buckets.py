"""Padded series (`bucketed_series`): one compiled program per bucket, the same numbers as unpadded.

`diagnose` pads each recording to its bucket's length and carries its split
as 0/1 weights, so that its compiled programs depend on the bucket and not on
the exact length (issue 30: a script diagnosing recordings of many lengths
died on its fifth call, out of memory maps). The reference for every number
here is the same problem built on the unpadded series.
"""

import jax.numpy as jnp
import numpy as np
import pytest

import hybrid as hy
from hybrid.core._problem import (
    BUCKET_STEPS,
    MIN_BUCKET,
    Problem,
    bucket_length,
    bucketed_series,
    series_from_recording,
)
from hybrid.util._programs import ProgramBudget, memory_maps


def test_buckets_cover_every_length_within_a_quarter():
    lengths = np.unique(np.geomspace(2, 2e6, 4000).astype(int))
    buckets = np.array([bucket_length(n) for n in lengths])
    assert np.all(buckets >= lengths)
    big = lengths >= MIN_BUCKET
    assert np.all(buckets[big] <= 1.25 * lengths[big])  # padding costs at most a quarter more samples
    assert np.all(np.diff(buckets) >= 0)
    # a few dozen buckets from 2 to 2·10⁶ samples, each a bucket of itself
    assert len(set(buckets)) <= len(BUCKET_STEPS) * 24
    assert all(bucket_length(b) == b for b in set(buckets))


def _recording(n, seed=0):
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.uniform(-1, 1, n // 10 + 1), 10)[:n]
    w = np.convolve(u, np.exp(-np.arange(30) / 6.0), mode="full")[:n] / 6 + 0.01 * rng.standard_normal(n)
    return hy.Recording(t=np.arange(n) / 30.0, v_in=u, w=w, name=f"n{n}")


def test_a_padded_problem_has_the_unpadded_costs_and_normal_equations():
    recordings = [_recording(700, 1), _recording(530, 2)]
    split, order = (0.6, 0.1, 0.3), ("train", "validation", "test")
    model = hy.Model(hy.LTI(1), hy.LinearReadout(), "physics")
    plain = [series_from_recording(r, split, order, blocks=3) for r in recordings]
    padded = [bucketed_series(s, bucket_length(s.v_in.shape[0]) + 7) for s in plain]
    a, b = Problem(model, plain), Problem(model, padded)
    theta = a.flatten(model) * 1.01
    assert float(a.scale) == pytest.approx(float(b.scale), rel=1e-12)
    assert float(b.cost(theta)) == pytest.approx(float(a.cost(theta)), rel=1e-10)
    assert float(b.validation_loss(theta)) == pytest.approx(float(a.validation_loss(theta)), rel=1e-10)
    JtJ_a, g_a = a.normal_equations(theta)
    JtJ_b, g_b = b.normal_equations(theta)
    np.testing.assert_allclose(
        np.asarray(JtJ_b), np.asarray(JtJ_a), rtol=1e-9, atol=1e-9 * float(jnp.max(JtJ_a))
    )
    np.testing.assert_allclose(
        np.asarray(g_b), np.asarray(g_a), rtol=1e-9, atol=1e-9 * float(jnp.max(jnp.abs(g_a)))
    )
    for split_name in order:  # the recorded samples, in the unpadded order
        np.testing.assert_allclose(
            b.recorded(b.target(split_name), split_name), np.asarray(a.target(split_name))
        )
        np.testing.assert_allclose(
            b.recorded(b.prediction(theta, split_name), split_name),
            np.asarray(a.prediction(theta, split_name)),
            rtol=1e-12,
            atol=1e-12,
        )


def test_the_budget_releases_programs_beyond_its_shapes():
    import jax

    budget = ProgramBudget(held=2, max_fraction=1.0)
    assert budget.admit("a") is False and budget.admit("b") is False and budget.admit("a") is False
    f = jax.jit(lambda x: jnp.sin(x) * 2)
    f(jnp.ones(3)).block_until_ready()
    assert f._cache_size() == 1
    assert budget.admit("c") is True  # a third shape: everything held so far is released
    assert f._cache_size() == 0 and budget.releases == 1 and budget.keys == ["c"]
    crowded = ProgramBudget(held=5, max_fraction=0.0)  # any maps at all count as crowded
    if memory_maps() is not None:
        assert crowded.admit("a") is True


@pytest.mark.skipif(not __import__("sys").platform.startswith("linux"), reason="/proc and glibc")
def test_releasing_programs_gives_the_freed_heap_back_to_the_system():
    """A loop of diagnoses over eight lengths held 1.09 GB resident where, the freed heap given back after
    each release (glibc's malloc_trim), it holds 0.92 GB. Half of 3000 blocks of 64 KB freed, in between
    live ones (holes glibc keeps for itself): a release gives most of those 96 MB back."""
    from hybrid.util._programs import _libc, release_programs

    if _libc() is None:
        pytest.skip("no glibc (malloc_trim) in this process")

    def resident_mb():
        with open("/proc/self/status") as status:
            return next(int(line.split()[1]) / 1e3 for line in status if line.startswith("VmRSS"))

    blocks = [np.ones(8000) for _ in range(3000)]  # 64 KB each: under glibc's mmap threshold
    del blocks[::2]
    held = resident_mb()
    release_programs()
    assert held - resident_mb() > 48.0  # half of the 96 MB freed, at least
    del blocks


def test_a_windowed_readout_refuses_padded_series():
    """A window reaches back across a split's start in a padded series: refused, not silently different."""
    series = bucketed_series(series_from_recording(_recording(300)), 320)
    model = hy.make_model("hybrid", simulation=hy.LTI(1), window=8, depth=2, width=4)
    with pytest.raises(hy.InputError, match="per-sample readout"):
        Problem(model, [series])


@pytest.mark.parametrize("rate", [30.0, 610.35])
def test_recordings_at_one_rate_share_their_step_and_programs_whatever_their_length(rate):
    """Times as a lab's file writes them (6 decimals) span a step that changes in its last bits with
    the length: the step is 1 / the rate to six digits, so a script diagnosing recordings of several
    lengths compiles its programs once per bucket and rate, not once per recording. (`diagnose`
    refused two such files of one 30 Hz camera together: "must share a sample rate, got [30.0,
    30.000000103] Hz".)"""
    import equinox as eqx

    from hybrid.util._programs import process_compiles

    lengths = range(2900, 3050, 7)  # one bucket (3072)
    times = [np.round(np.arange(n) / rate, 6) for n in lengths]
    assert len({t[-1] / (len(t) - 1) for t in times}) > 1  # the spans' steps differ ...
    recordings = [hy.Recording(t=t, v_in=np.sin(t), w=np.cos(t)) for t in times]
    assert len({r.dt for r in recordings}) == 1  # ... the step does not,
    assert recordings[0].rate == pytest.approx(rate, rel=5e-6)  # within 5 ppm
    assert recordings[0].dt == 1.0 / rate  # a rate of six digits is kept to the bit

    model = hy.Model(hy.LTI(1), hy.LinearReadout(), "physics")
    cost = eqx.filter_jit(lambda problem, theta: problem.cost(theta))
    counter = process_compiles()
    compiled = []
    for r in recordings[:3]:
        series = series_from_recording(r)
        problem = Problem(model, [bucketed_series(series, bucket_length(r.n))])
        before = counter["programs"]
        cost(problem, problem.flatten(model)).block_until_ready()
        compiled.append(counter["programs"] - before)
    assert compiled[0] > 0 and compiled[1:] == [0, 0]


def test_a_rate_of_more_digits_is_rounded_to_six():
    t = np.arange(4000) / 30.00314159
    r = hy.Recording(t=t, v_in=np.zeros_like(t), w=np.zeros_like(t))
    assert r.rate == 30.0031  # to the sixth digit: 1.4 ppm here


def test_fit_keeps_the_programs_of_its_last_lengths_and_releases_a_crowded_process(monkeypatch):
    """`fit` compiles for each recording's length (about 700 maps and 85 MB each for a small plug-in: a
    probe's loop over 30 lengths grew to 3.1 GB): it keeps the programs of its last `held` shape keys,
    releases every compiled program for one more, and releases them in a crowded process whatever the key."""
    import jax

    from hybrid.core import _fit

    if memory_maps() is None:
        pytest.skip("no /proc/self/maps here: nothing to guard")
    model = hy.Model(hy.LTI(1), hy.LinearReadout(), "physics")
    solver = hy.LevenbergMarquardt(max_steps=2)
    f = jax.jit(lambda x: jnp.cos(x) + 1)

    def cached_after_fit(n):
        f(jnp.ones(4)).block_until_ready()
        hy.fit(model, _recording(n), solver=solver, progress=False)
        return f._cache_size()

    budget = ProgramBudget(held=2)
    monkeypatch.setattr(_fit, "FIT_PROGRAMS", budget)
    assert [cached_after_fit(n) for n in (300, 300, 310)] == [1, 1, 1]  # two lengths: kept
    assert budget.releases == 0
    assert cached_after_fit(320) == 0 and budget.releases == 1  # a third: released first
    monkeypatch.setattr(_fit, "FIT_PROGRAMS", ProgramBudget(held=5, max_fraction=0.0))  # any maps: crowded
    assert cached_after_fit(320) == 0


_CLOSURE_LAG = """
from typing import ClassVar

import jax
import jax.numpy as jnp

import hybrid as hy


class ClosureLag(hy.AbstractSimulation):
    \"\"\"A first-order lag whose lax.scan steps a function defined inside simulate, as plug-ins write it.\"\"\"

    raw: dict
    constraints: ClassVar[dict] = {"tau": hy.Positive()}
    units: ClassVar[dict] = {"tau": "s"}
    typical: ClassVar[dict] = {"tau": (0.05, 5.0)}
    linear_in_drive: ClassVar[bool] = True
    output_unit: ClassVar[str] = "{drive}"

    def __init__(self, tau=0.5):
        self.raw = hy.encode({"tau": tau}, self.constraints, "ClosureLag")

    def simulate(self, v_in, dt):
        v_in, dt = hy.check_drive(v_in, dt, "ClosureLag.simulate")
        a = jnp.exp(-dt / self.parameters()["tau"])

        def step(x, u):
            x = a * x + (1 - a) * u
            return x, x

        return jax.lax.scan(step, jnp.zeros((), v_in.dtype), v_in)[1]
"""

_LOOP = """
import json, sys
import jax
jax.config.update("jax_enable_x64", True)
import numpy as np
import hybrid as hy
from hybrid.util._programs import process_compiles

ClosureLag = type(hy.resolve_physics(sys.argv[1] + ":ClosureLag"))
data = np.load(sys.argv[2])
recording = hy.Recording(t=data["t"], v_in=data["v_in"], w=data["w"])
counter = process_compiles()
out = []
for _ in range(3):
    before = counter["programs"]
    result = hy.fit(hy.make_model("physics", simulation=ClosureLag()), recording, progress=False)
    out.append([counter["programs"] - before, float(result.model.parameters()["tau"])])
print("RESULT " + json.dumps(out))
"""


def test_fits_of_one_length_in_a_loop_compile_nothing_after_the_first(tmp_path):
    """A probe's loop of fits of one length with a plug-in like `_CLOSURE_LAG` compiled 14 programs a fit
    (its predictions on each part, run op by op, scanned a new closure each time) and grew 20 MB a fit.
    Three fits in a script of its own, the last two compiling nothing (the counter counts the whole
    process: in the full suite the second fit counted 3 compiles it does not count alone)."""
    import json
    import subprocess
    import sys

    (tmp_path / "closure_lag.py").write_text(_CLOSURE_LAG)
    r = _recording(400, 3)
    np.savez(tmp_path / "rec.npz", t=r.t, v_in=r.v_in, w=r.w)
    run = subprocess.run(
        [sys.executable, "-c", _LOOP, str(tmp_path / "closure_lag.py"), str(tmp_path / "rec.npz")],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert run.returncode == 0, run.stderr[-2000:]
    (line,) = [x for x in run.stdout.splitlines() if x.startswith("RESULT ")]
    (c0, tau0), (c1, tau1), (c2, tau2) = json.loads(line[len("RESULT ") :])
    assert c0 > 0 and (c1, c2) == (0, 0), (c0, c1, c2)
    assert tau0 == tau1 == tau2  # the same fit each time
    assert 0.1 < tau0 < 0.3  # the data's lag: e^(-1/30/τ) of a 6-sample (0.2 s) kernel
