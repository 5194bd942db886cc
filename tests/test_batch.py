"""fit_batch: one compiled program for many recordings × starts, equal to fits one by one.

Sizes are tiny (N = 10 stages; D-MLP 2 × 4 on a 5-sample window; 1,200 samples).
The sharded run needs several devices, so it runs in a subprocess with
``XLA_FLAGS=--xla_force_host_platform_device_count=4`` (CPU "devices").
"""

import dataclasses
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import equinox as eqx
import helpers as h
import jax
import numpy as np
import pytest

from hybrid import InputError, LevenbergMarquardt, RCNetwork, Recording, fit, fit_batch, make_model

TINY = dict(window=5, depth=2, width=4)


def _strips(n):
    """Planted physics recordings of n strips that differ in ξρ, C_clamp and gain."""
    return [
        h.planted_physics_recording(
            RCNetwork(xi_rho=6.0 * (1 + 0.1 * i), alpha_C=0.4, C_clamp=0.02 * (1 + 0.05 * i), n_stages=10),
            1.7 - 0.1 * i,
            0.3,
            0.01,
            seed=i,
        )
        for i in range(n)
    ]


def _max_relative_difference(a, b):
    return max(abs(a[k] - b[k]) / max(abs(b[k]), 1e-12) for k in b)


def test_physics_batch_equals_one_by_one():
    recordings = _strips(2)
    start = make_model("physics", simulation=RCNetwork(n_stages=10))
    options = dict(frozen={"xi_h"}, starts=2, solver=LevenbergMarquardt(max_steps=40))
    batch = fit_batch(start, recordings, **options)
    assert len(batch) == 2 and batch.batch == 4 and batch.devices == len(jax.devices())
    for result, recording in zip(batch, recordings):
        single = fit(start, recording, progress=False, **options)
        # same starts, same LM iterations: equal to rounding amplified by ≤ 40 LM steps
        # (measured ≤ 2e-9 relative); same start chosen, same step counts
        assert _max_relative_difference(result.parameters, single.parameters) < 1e-6
        assert result.best_start == single.best_start
        assert [s["steps"] for s in result.starts] == [s["steps"] for s in single.starts]
        for split in ("train", "validation", "test"):
            assert result.metrics[split]["nmse"] == pytest.approx(single.metrics[split]["nmse"], rel=1e-6)
    # the recordings differ: so do the fits
    assert batch[0].parameters["gain"] != pytest.approx(batch[1].parameters["gain"], rel=0.01)


def test_a_plugin_physics_batch_equals_one_by_one():
    """Any simulation batches as the RC network does: here LTI(1) held at a fitted drive before each record.

    The records are numpy's exact ZOH response of 1/(1 + s·tau) from the held drive.
    """
    from hybrid import LTI, HeldStart, Recording

    rng = np.random.default_rng(0)
    recordings = []
    for tau, held in [(2.0, 0.5), (3.0, -0.4)]:
        u = np.repeat(rng.uniform(-1, 1, 20), 20)
        a, y, state = np.exp(-0.1 / tau), np.empty(u.size), held
        for k in range(u.size):
            y[k], state = state, a * state + (1 - a) * u[k]
        recordings.append(
            Recording(t=np.arange(u.size) * 0.1, v_in=u, w=1.5 * y + 0.01 * rng.normal(size=u.size))
        )
    start = make_model("physics", simulation=HeldStart(LTI(1), 100))
    options = dict(frozen={"direct"}, solver=LevenbergMarquardt(max_steps=30), split=(0.6, 0.2, 0.2))
    batch = fit_batch(start, recordings, **options)
    # each fit recovers its own planted system (batch = one by one is shown for the RC network above)
    for result, (tau, held) in zip(batch, [(2.0, 0.5), (3.0, -0.4)]):
        assert result.parameters["tau_1"] == pytest.approx(tau, rel=0.05)
        assert result.parameters["initial_drive"] == pytest.approx(held, abs=0.05)


def test_hybrid_batch_in_chunks_equals_one_by_one():
    recordings = _strips(2)
    start = make_model("hybrid", simulation=RCNetwork(n_stages=10), **TINY)
    options = dict(frozen={"xi_h"}, solver=LevenbergMarquardt(max_steps=10), weight_decay=0.01)
    batch = fit_batch(start, recordings, batch_size=1, **options)
    assert batch[0].parameters["xi_rho"] != batch[1].parameters["xi_rho"]
    for result, recording in zip(batch[:1], recordings[:1]):  # one reference fit: compile time
        single = fit(start, recording, progress=False, **options)
        assert _max_relative_difference(result.parameters, single.parameters) < 1e-6
        assert result.metrics["test"]["nmse"] == pytest.approx(single.metrics["test"]["nmse"], rel=1e-6)
        leaves_b = jax.tree_util.tree_leaves(eqx.filter(result.model.readout.mlp, eqx.is_array))
        leaves_s = jax.tree_util.tree_leaves(eqx.filter(single.model.readout.mlp, eqx.is_array))
        assert max(float(np.max(np.abs(a - b))) for a, b in zip(leaves_b, leaves_s)) < 1e-6


def test_a_second_batch_of_the_same_shapes_compiles_nothing_and_near_rates_are_one_rate():
    from hybrid.util._programs import compile_counter

    start = make_model("physics", simulation=RCNetwork(n_stages=10))
    options = dict(frozen={"xi_h"}, solver=LevenbergMarquardt(max_steps=10))
    first = fit_batch(start, _strips(2), **options)
    counter = compile_counter()
    again = _strips(3)[1:]  # other data, the same shapes
    # a time column stored with 6 decimals: the median step puts the rate 1e-5 off 30 Hz
    rounded = dataclasses.replace(again[1], t=np.round(np.asarray(again[1].t) * 1.00001, 6))
    assert rounded.rate != again[0].rate and rounded.n == again[0].n
    second = fit_batch(start, [again[0], rounded], **options)
    assert counter["programs"] == 0 and second.compile_seconds == 0.0  # the first call's program
    assert first[1].parameters == pytest.approx(second[0].parameters, rel=1e-12)  # the same strip
    with pytest.raises(InputError, match="one sample rate"):
        fit_batch(
            start, [again[0], dataclasses.replace(again[1], t=np.asarray(again[1].t) * 1.01)], **options
        )


def test_fit_batch_rejects_bad_input():
    recordings = _strips(2)
    start = make_model("physics", simulation=RCNetwork(n_stages=10))
    short = recordings[1].segment(slice(0, 900))
    with pytest.raises(InputError, match="one length"):
        fit_batch(start, [recordings[0], short])
    with pytest.raises(InputError):
        fit_batch(start, [])
    with pytest.raises(InputError):
        fit_batch(start, recordings, starts=0)
    with pytest.raises(InputError):
        fit_batch(start, recordings, batch_size=0)
    # a strip that rests through its training part (the first 30 %) is named, not fitted to its start
    quiet = Recording(
        t=recordings[1].t,
        v_in=np.where(np.arange(recordings[1].n) < 0.35 * recordings[1].n, 0.0, recordings[1].v_in),
        w=recordings[1].w,
    )
    with pytest.raises(InputError, match=r"at rest in the training part.*Trim recording 1's quiet start"):
        fit_batch(start, [recordings[0], quiet])
    # rows of quality 0 (rig's: w not measured) at other samples than recording 0's: a split of its own,
    # which one compiled program cannot hold (it was a tree-structure mismatch from jax)
    held = dataclasses.replace(
        recordings[1], extra={"quality": np.where(np.arange(recordings[1].n) % 97 < 3, 0.0, 1.0)}
    )
    with pytest.raises(
        InputError, match=r"recording 1 .* has rows of quality 0 .* one by one with hybrid.fit"
    ):
        fit_batch(start, [recordings[0], held])


SHARDED = textwrap.dedent("""
    import json, sys
    sys.path.insert(0, {tests!r})
    import jax
    jax.config.update("jax_enable_x64", True)
    from test_batch import _strips
    from hybrid import LevenbergMarquardt, RCNetwork, fit_batch, make_model

    recordings = _strips(3)
    start = make_model("physics", simulation=RCNetwork(n_stages=10))
    options = dict(frozen={{"xi_h"}}, solver=LevenbergMarquardt(max_steps=40))
    sharded = fit_batch(start, recordings, **options)
    single = fit_batch(start, recordings, devices=jax.devices()[:1], **options)
    print(json.dumps({{
        "device_count": jax.device_count(),
        "devices": sharded.devices,
        "sharded": [r.parameters for r in sharded],
        "single": [r.parameters for r in single],
    }}))
""")


def test_sharded_batch_over_four_cpu_devices_equals_unsharded():
    tests = str(Path(__file__).parent)
    # The suite's flags (conftest: the quick-compile emitters) stay; the device count is added to them.
    flags = f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count=4".strip()
    env = {**os.environ, "XLA_FLAGS": flags, "JAX_PLATFORMS": "cpu"}
    env.pop("JAX_NUM_CPU_DEVICES", None)  # the suite's one device (conftest) would win over the flag
    proc = subprocess.run(
        [sys.executable, "-c", SHARDED.format(tests=tests)],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["device_count"] == 4 and out["devices"] == 4
    # 3 fits padded to 4, one per device, vs all 3 vmapped on one device:
    # equal to rounding (measured ≤ 1e-9 relative)
    for a, b in zip(out["sharded"], out["single"]):
        assert _max_relative_difference(a, b) < 1e-6


def test_simulate_batch_equals_simulate_one_by_one():
    from hybrid import simulate_batch

    nets = [RCNetwork(xi_rho=5.0 + i, C_clamp=0.01 * (1 + i), n_stages=12) for i in range(5)]
    v = h.step_drive(700, seed=2)
    expected = np.stack([np.asarray(n.simulate(v, 1 / 30)) for n in nets])
    for batch_size in (None, 2):  # 5 = 2 + 2 + 1: a ragged last chunk
        got = np.asarray(simulate_batch(nets, v, 1 / 30, batch_size=batch_size))
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-13 * np.max(np.abs(expected)))
    # one drive per simulation
    drives = np.stack([v * (i + 1) for i in range(5)])
    got = np.asarray(simulate_batch(nets, drives, 1 / 30))
    np.testing.assert_allclose(
        got, expected * np.arange(1, 6)[:, None], rtol=0, atol=1e-12 * np.max(np.abs(expected))
    )
    with pytest.raises(InputError):
        simulate_batch([], v, 1 / 30)
    with pytest.raises(InputError, match="one shape"):  # 12 stages and 10: no common batch
        simulate_batch([nets[0], RCNetwork(n_stages=10)], v, 1 / 30)
    with pytest.raises(InputError, match="one drive per simulation"):
        simulate_batch(nets, drives[:3], 1 / 30)
