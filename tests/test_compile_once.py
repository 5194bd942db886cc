"""A long session never runs out of memory maps: `diagnose` compiles once per bucket of lengths (issue 30).

A script called `hybrid.diagnose` on recordings of 600, 737, 874, 1,011 and
1,148 samples in one process; each call compiled ~13,800 memory maps' worth of
programs for its own length, and the fifth died (SIGSEGV) at Linux's 65,530.
Here eight recordings of eight lengths that share a bucket are diagnosed in
one process: after the first call no large program is compiled again and the
maps stop growing, though they are split into different numbers of
blocks; and within one diagnosis each screen, the lanes and the predictions
compile once across its steps, a third step included.
(That programs are released beyond two buckets is
`tests/test_buckets.py`'s; `benchmarks/diagnose_many.py` runs 55 calls over
many lengths and two simulations.)
"""

import collections

import jax
import numpy as np
from jax import monitoring

import hybrid as hy
from hybrid.core._problem import bucket_length
from hybrid.discovery._search import held_out_blocks
from hybrid.util._programs import memory_maps

#: Eight lengths in one bucket (257–320 samples: ~10 s at 30 Hz).
LENGTHS = (300, 263, 317, 281, 309, 290, 271, 312)

_compiles = collections.Counter()


def _listen(event, duration, fun_name=None, **_):
    if event == "/jax/core/compile/backend_compile_duration":  # compiled, or read from the disk cache
        _compiles["n"] += 1
        _compiles["large"] += duration > 1.0  # a search program, not an eager op's
        _compiles[fun_name] += 1  # e.g. "jit(loop_screen)"


monitoring.register_event_duration_secs_listener(_listen)


def _recording(n, seed, drift=0.0):
    """A first-order lag with a saturating output, 30 Hz (the issue's case), made here in numpy.

    `drift`: the output's gain grows linearly by this fraction over the record (a second effect).
    """
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.uniform(-1, 1, n // 12 + 1), 12)[:n]
    a = np.exp(-1.0 / (30.0 * 0.4))
    y = np.zeros(n)
    for k in range(1, n):
        y[k] = a * y[k - 1] + (1 - a) * u[k - 1]
    gain = 1.0 + drift * np.arange(n) / n
    w = gain * np.tanh(2.0 * y) / 2.0 + 0.003 * rng.standard_normal(n)
    t = np.round(np.arange(n) / 30.0, 6)  # as a file holds it: each span's step differs in its last bits
    return hy.Recording(t=t, v_in=u, w=w, name=f"lag {n}")


def test_diagnose_on_eight_lengths_compiles_once_and_the_maps_stop_growing():
    assert len({bucket_length(n) for n in LENGTHS}) == 1 and len(set(LENGTHS)) == len(LENGTHS)
    settings = hy.DiagnoseSettings(max_steps=20)
    # What is counted (programs, maps) does not depend on which effects are searched: three
    # rivals keep the answer a search's (saturation against a delay and a gain drift) at 16
    # lanes a stage instead of the default set's 21.
    effects = ("delay", "saturation", "drift")
    # Some of these saturating records sit flat at an extreme where 3 blocks' held-out parts miss
    # it, and are split into more (`held_out_blocks`): the programs must not depend on the count.
    blocks = {held_out_blocks([_recording(n, seed)], settings)[0] for seed, n in enumerate(LENGTHS)}
    assert len(blocks) > 1, blocks
    jax.clear_caches()  # other tests' programs out of the count
    maps, large, causes = [], [], []
    for seed, n in enumerate(LENGTHS):
        before = _compiles["large"]
        found = hy.diagnose(_recording(n, seed), simulation=hy.LTI(1), effects=effects, settings=settings)
        causes.append(found.cause)
        large.append(_compiles["large"] - before)
        maps.append(memory_maps())
    assert large[0] > 0  # the first call compiled the search
    assert large[2:] == [0] * (len(LENGTHS) - 2), large  # then nothing large, whatever the length
    if maps[0] is not None:
        assert maps[-1] < 1.1 * maps[1], maps  # the maps stop growing
    assert causes.count("saturation") >= 6, causes  # and the answers are the search's, not a stub's


def test_a_simulation_called_op_by_op_compiles_once_per_structure_and_length():
    """`simulate` outside jit: the second call, at other parameter values, compiles nothing.

    Called op by op, each `lax.scan` of the RC network's cascade compiled its body
    afresh at every call (a new closure each time): ~0.4 s a call for 1,800 samples,
    in any script that simulates in a Python loop. The built-in simulations, a
    state-space plug-in and an effect stack around either now run one compiled
    program per structure and length (`hybrid.core._arguments.run_compiled`).
    """
    from pathlib import Path

    from hybrid.discovery._effect_stack import EffectStack

    examples = Path(__file__).resolve().parents[1] / "examples"
    MassSpringDamper = type(hy.resolve_physics(f"{examples}/oscillator.py:MassSpringDamper"))

    drive = np.sin(np.arange(240) / 7.0)
    makers = {
        "RCNetwork": lambda k: hy.RCNetwork(xi_rho=8.0 + k),
        "RCNetwork zoh": lambda k: hy.RCNetwork(xi_rho=8.0 + k, method="zoh"),
        "LTI(2)": lambda k: hy.LTI(2).replace(f_1=1.0 + k),
        "plug-in": lambda k: MassSpringDamper(frequency=2.0 + k),
        "stack": lambda k: EffectStack(hy.RCNetwork(xi_rho=8.0 + k), ["saturation", "delay"]),
        "stack inside": lambda k: EffectStack(MassSpringDamper(frequency=2.0 + k), ["stiffness"]),
    }
    for name, make in makers.items():
        first = np.asarray(make(0).simulate(drive, 1 / 30))
        before = _compiles["n"]
        second = np.asarray(make(1).simulate(drive, 1 / 30))
        assert _compiles["n"] == before, f"{name}: compiled {_compiles['n'] - before} programs again"
        assert np.all(np.isfinite(second)) and not np.allclose(first, second), name
        # the compiled program is the same computation as the simulation inside a user's own jit
        inside = np.asarray(jax.jit(lambda s, v: s.simulate(v, 1 / 30))(make(1), drive))
        np.testing.assert_allclose(second, inside, rtol=1e-12, atol=1e-12 * np.max(np.abs(inside)))


def test_a_diagnosis_compiles_each_program_once_across_its_steps():
    """Every step screens its starts and runs its lanes with the programs of the first step.

    The first step screens the stack with every effect off, the later steps the
    stack with the named ones on: the same structure, so `loop_screen`,
    `mode_screen` and `screen_losses` each compile (or load) once per diagnosis,
    counted per program by JAX's own events. Before, the first step screened the
    simulation itself, outside the stack, and every later step compiled its
    screens again. A third step (two causes named) runs its lanes on the same
    problem too: the lanes' program and `predictions` compile once (a third step
    compiled a larger problem's, ~10 s on a 60 s recording of the RC network).
    """
    programs = (
        "jit(screen_losses)",
        "jit(loop_screen)",
        "jit(mode_screen)",
        "jit(predictions)",
        "jit(_fit_lanes_compiled)",
        "jit(_fit_lanes_sharded)",
    )
    jax.clear_caches()  # other tests' programs out of the count
    before = {name: _compiles[name] for name in programs}
    found = hy.diagnose(
        _recording(300, 11, drift=0.5),
        simulation=hy.LTI(1),
        effects=("saturation", "drift", "hysteresis", "resonance"),
        settings=hy.DiagnoseSettings(max_steps=20),
    )
    named = [c["name"] for c in found.causes]
    assert len(found.steps) == 3 and sorted(named) == ["drift", "saturation"], named  # a third step ran
    counts = {name: _compiles[name] - before[name] for name in programs}
    lanes = counts.pop("jit(_fit_lanes_compiled)") + counts.pop("jit(_fit_lanes_sharded)")
    assert lanes == 1 and all(n == 1 for n in counts.values()), (lanes, counts)
