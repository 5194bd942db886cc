"""Continuous-time reference for the RC network, by diffrax (an independent ODE solver).

Solves ẋ = A x + B u(t), V_o = C x + D u(t) for the cascade's state-space
realisation between the sample times, with the drive held constant (``hold="zoh"``)
or linearly interpolated (``hold="linear"``) over each interval. It is slow and
meant for checking the discretisations, not for fitting.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import lax

from ..util._errors import InputError


def reference_response(network, v_in, dt, *, hold="zoh", rtol=1e-10, atol=1e-12):
    """V_o at the sample times for the drive `v_in`, from rest, by adaptive Kvaerno5."""
    import diffrax  # here, not at import: half a second of every CLI process that never solves an ODE

    if hold not in ("zoh", "linear"):
        raise InputError(f"hold must be 'zoh' or 'linear', got {hold!r}")
    A, B, C, D = network.state_space()
    v_in = jnp.asarray(v_in, A.dtype)
    v_next = jnp.concatenate([v_in[1:], v_in[-1:]])
    solver = diffrax.Kvaerno5()
    controller = diffrax.PIDController(rtol=rtol, atol=atol)

    def vector_field(t, x, args):
        u0, u1 = args
        u = u0 if hold == "zoh" else u0 + (u1 - u0) * t / dt
        return A @ x + B * u

    term = diffrax.ODETerm(vector_field)

    def interval(x, inputs):
        u0, u1 = inputs
        y = C @ x + D * u0
        sol = diffrax.diffeqsolve(
            term,
            solver,
            0.0,
            dt,
            dt / 4,
            x,
            args=(u0, u1),
            stepsize_controller=controller,
            max_steps=10_000,
        )
        return sol.ys[-1], y

    _, y = lax.scan(interval, jnp.zeros(A.shape[0], A.dtype), (v_in, v_next))
    return y
