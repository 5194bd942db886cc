"""The LAPACK-free linear algebra that `diagnose`'s batched loops run on (issue 20).

References: scipy.linalg.expm / expm_frechet and numpy.linalg.lstsq. And the
structural guard: no compiled program of diagnose's screens (nor a batched
ZOH simulation) contains a LAPACK custom call, the construct that deadlocks
jaxlib 0.10's CPU runtime (`experiments/xla_cpu_deadlock.py`).
"""

import re
import subprocess
import sys
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg

from hybrid import RCNetwork
from hybrid.core._loop_safe_linalg import expm, lstsq

ROOT = Path(__file__).resolve().parents[1]


def _augmented(network, dt):
    A, B, _, _ = (np.asarray(x) for x in network.state_space())
    n = A.shape[0]
    m = np.zeros((n + 1, n + 1))
    m[:n, :n], m[:n, n] = A, B
    return m * dt


@pytest.mark.parametrize(
    "c_clamp,xi_rho,dt",
    [(1e-3, 1.0, 1 / 30), (1e-3, 1.0, 10.0), (3e-2, 10.0, 1e-5), (1.0, 100.0, 10.0), (3e-2, 100.0, 1 / 30)],
)
def test_expm_matches_scipy_on_the_rc_networks_zoh_matrix(c_clamp, xi_rho, dt):
    """The stiff, lower-triangular ZOH matrices of the RC network, ‖AΔt‖₁ from 1e-4 to 2e4: 1e-12 relative."""
    m = _augmented(RCNetwork(xi_rho=xi_rho, C_clamp=c_clamp, alpha_E=0.2, alpha_I=0.8, alpha_C=0.3), dt)
    ref = scipy.linalg.expm(m)
    got = np.asarray(expm(jnp.asarray(m)))
    assert np.max(np.abs(got - ref)) <= 1e-12 * np.max(np.abs(ref))


def test_expm_general_matrices_and_its_derivative_match_scipy():
    rng = np.random.default_rng(3)
    for scale in (1e-3, 0.7, 5.0, 60.0):
        a = rng.standard_normal((6, 6)) * scale / 6 - np.eye(6) * scale / 3
        e = rng.standard_normal((6, 6))
        ref, ref_d = scipy.linalg.expm_frechet(a, e)
        got, got_d = jax.jvp(expm, (jnp.asarray(a),), (jnp.asarray(e),))
        assert np.allclose(np.asarray(got), ref, rtol=1e-11, atol=1e-13 * np.abs(ref).max())
        assert np.allclose(np.asarray(got_d), ref_d, rtol=1e-9, atol=1e-11 * np.abs(ref_d).max())


def test_expm_reverse_mode_matches_finite_differences():
    a = jnp.asarray(np.random.default_rng(4).standard_normal((4, 4)))
    g = jax.grad(lambda x: jnp.sum(expm(x) ** 2))(a)
    h = 1e-6
    fd = np.zeros((4, 4))
    for i in range(4):
        for j in range(4):
            d = np.zeros((4, 4))
            d[i, j] = h
            fd[i, j] = (
                np.sum(scipy.linalg.expm(np.asarray(a) + d) ** 2)
                - np.sum(scipy.linalg.expm(np.asarray(a) - d) ** 2)
            ) / (2 * h)
    assert np.allclose(np.asarray(g), fd, rtol=1e-6, atol=1e-8)


def test_expm_beyond_its_squarings_is_nan_not_garbage():
    assert np.all(np.isnan(np.asarray(expm(-jnp.eye(3) * 2.0**12, max_squarings=8))))


def test_lstsq_matches_numpy_and_is_vmappable():
    rng = np.random.default_rng(5)
    designs = rng.standard_normal((3, 400, 4))
    targets = rng.standard_normal((3, 400))
    coef, rss = jax.vmap(lstsq)(jnp.asarray(designs), jnp.asarray(targets))
    for i in range(3):
        ref, ref_rss, *_ = np.linalg.lstsq(designs[i], targets[i], rcond=None)
        assert np.allclose(np.asarray(coef[i]), ref, rtol=1e-12, atol=1e-14)
        assert np.isclose(float(rss[i]), ref_rss[0], rtol=1e-11)


def test_lstsq_with_a_dependent_column_keeps_the_minimum_residual():
    rng = np.random.default_rng(6)
    x = rng.standard_normal((300, 3))
    design = np.c_[x, 2.0 * x[:, 0]]
    y = rng.standard_normal(300)
    coef, rss = lstsq(jnp.asarray(design), jnp.asarray(y))
    ref = np.linalg.lstsq(design, y, rcond=None)[0]
    assert float(coef[3]) == 0.0
    assert np.isclose(float(rss), np.sum((design @ ref - y) ** 2), rtol=1e-12)
    assert np.allclose(design @ np.asarray(coef), design @ ref, atol=1e-12)


def _lapack_calls(lowered) -> set[str]:
    return set(re.findall(r"custom_call @(\w*lapack\w*)", lowered.as_text()))


def test_no_lapack_call_in_diagnoses_batched_screens_on_two_recordings():
    """The hang's construct cannot come back unseen: a batched LAPACK call inside these loops fails here."""
    from hybrid.core._screen import design_raws, screen_losses, start_design
    from hybrid.data._drives import make_drive
    from hybrid.discovery._diagnosis import DiagnoseSettings
    from hybrid.discovery._search import lanes_problem
    from hybrid.discovery._starts import (
        LOOP_RATES,
        N_JOINT_SCREEN,
        loop_screen,
        mode_frequencies,
        mode_screen,
    )
    from hybrid.ipmc._virtual_ipmc import virtual_recording

    recordings = [virtual_recording(make_drive("prbs", 70.0, rate=30.0, seed=s), seed=s) for s in (1, 2)]
    sim = RCNetwork(method="zoh")
    problem, *_ = lanes_problem(recordings, sim, DiagnoseSettings())
    _, raws = design_raws(sim, start_design(sim, N_JOINT_SCREEN, {"xi_h"}))
    freqs = mode_frequencies(30.0)[:2]
    lowered = {
        "screen_losses": jax.jit(lambda r: screen_losses(problem, sim, r)).lower(raws),
        "loop_screen": jax.jit(lambda r: loop_screen(problem, sim, r, LOOP_RATES)).lower(raws),
        "mode_screen": jax.jit(lambda r: mode_screen(problem, sim, r, freqs, np.array([0.1, 0.3]))).lower(
            raws
        ),
        "vmapped zoh simulation": jax.jit(
            jax.vmap(
                lambda raw: eqx.tree_at(lambda s: s.raw, sim, {**sim.raw, "C_clamp": raw}).simulate(
                    recordings[0].v_in, 1 / 30
                )
            )
        ).lower(jnp.linspace(-3.0, 0.0, 4)),
    }
    found = {name: _lapack_calls(low) for name, low in lowered.items()}
    assert all(not calls for calls in found.values()), found


def test_the_reproducers_loop_safe_variant_completes_in_a_fresh_process(tmp_path):
    """The reproducer's construct with the LAPACK-free expm, in a subprocess with a watchdog."""
    out = tmp_path / "deadlock.json"
    proc = subprocess.run(
        [
            sys.executable,
            "experiments/xla_cpu_deadlock.py",
            "--variant",
            "loop_safe_expm",
            "--runs",
            "1",
            "--timeout",
            "120",
            "--out",
            str(out),
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    assert "loop_safe_expm           completed 1/1, hung 0" in proc.stdout
