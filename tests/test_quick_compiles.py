"""`hybrid.use_quick_compiles`: XLA:CPU's loop emitters at LLVM's level 1 for an entry point, the user's choices kept.

XLA reads ``XLA_FLAGS`` once, when its backend starts, and stops the process on
a flag it does not know: each case runs in a fresh process, which also shows
that the jaxlib installed accepts the flags. Both settings must compute the same
functions: an effect stack's output and its Jacobian (a scan, a Bouc–Wen loop, a
mode and the RC network's cascade, forward-mode through all of them), compiled
with the quick compiles and with XLA's defaults (fusion emitters, level 2), agree
to rounding.
"""

import json
import os
import subprocess
import sys
import textwrap

import numpy as np

STACK = textwrap.dedent("""
    import json, os, sys
    import hybrid
    added = hybrid.use_quick_compiles()
    if sys.argv[1:] == ["--flags-only"]:
        print(json.dumps({"added": added, "flags": os.environ.get("XLA_FLAGS", "")}))
        raise SystemExit
    import equinox as eqx
    import jax
    import jax.flatten_util
    import numpy as np
    from hybrid.discovery._effect_stack import extend
    jax.config.update("jax_enable_x64", True)
    stack = extend(hybrid.RCNetwork(method="zoh"), "saturation", "hysteresis", "resonance")
    params, static = eqx.partition(stack, stack.trainable(frozenset()))
    flat, unravel = jax.flatten_util.ravel_pytree(params)
    v = jax.numpy.asarray(hybrid.make_drive("prbs", 10.0, seed=1).v)
    run = jax.jit(lambda x: eqx.combine(unravel(x), static).simulate(v, 1 / 30))
    print(json.dumps({
        "added": added,
        "flags": os.environ.get("XLA_FLAGS", ""),
        "y": np.asarray(run(flat)).tolist(),
        "J": np.asarray(jax.jacfwd(run)(flat)).tolist(),
    }))
""")


def _stack(*args, **env):
    proc = subprocess.run(
        [sys.executable, "-c", STACK, *args],
        capture_output=True,
        text=True,
        env={**{k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}, **env},
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_quick_compiles_set_the_flags_keep_the_users_choice_and_compute_the_same():
    quick = _stack()
    assert quick["added"] is True
    assert quick["flags"].split() == [
        "--xla_cpu_use_fusion_emitters=false",
        "--xla_backend_optimization_level=1",
    ]
    # The user's choices win (here XLA's defaults), and other flags they set stay as they were.
    defaults = "--xla_cpu_use_fusion_emitters=true --xla_backend_optimization_level=2 --xla_cpu_enable_fast_math=false"
    chosen = _stack(XLA_FLAGS=defaults)
    assert chosen["added"] is False and chosen["flags"] == defaults
    y, J = np.asarray(quick["y"]), np.asarray(quick["J"])
    assert J.shape == (300, 13) and np.all(np.isfinite(J)) and np.max(np.abs(J)) > 0
    np.testing.assert_allclose(y, chosen["y"], rtol=0, atol=1e-12 * np.max(np.abs(y)))
    np.testing.assert_allclose(J, chosen["J"], rtol=0, atol=1e-12 * np.max(np.abs(J)))


def test_quick_compiles_add_to_the_users_other_flags_option_by_option():
    other = _stack("--flags-only", XLA_FLAGS="--xla_cpu_enable_fast_math=false")
    assert other["added"] is True
    assert other["flags"].split() == [
        "--xla_cpu_enable_fast_math=false",
        "--xla_cpu_use_fusion_emitters=false",
        "--xla_backend_optimization_level=1",
    ]
    # a user who chose the level keeps it and gets the loop emitters beside it
    level = _stack("--flags-only", XLA_FLAGS="--xla_backend_optimization_level=3")
    assert level["added"] is True
    assert level["flags"].split() == [
        "--xla_backend_optimization_level=3",
        "--xla_cpu_use_fusion_emitters=false",
    ]
