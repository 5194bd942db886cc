"""`diagnose`'s lanes and screens side by side on several CPU devices: the same numbers as on one (issue 30).

`hybrid.use_cpu_cores` gives JAX one CPU device per core (the `hybrid`
command calls it); `fit_lanes` then deals its lanes out to the devices, lane i
to device i mod d, and the screens (`hybrid.core._devices.map_rows`) give each
device a block of design points. Each device runs its share one after
another, so every lane's and every point's arithmetic is the one it has on a
single device:

- five distinct lanes on three devices (one padding lane) against the same
  five run by the unsharded program in the same process: a lane that came back
  in another lane's row, or a padding lane that leaked into the result, fails;
- the same lanes stopped by a shorter patience, or capped at a few steps, and
  resumed (`resume`) against the longer patience from the start: equal to the
  last bit;
- the four screens on a 40-point design (not a multiple of three) on three
  devices against a process with one.

The device count is fixed when JAX starts, so each case runs in a subprocess.
"""

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

LANES = textwrap.dedent("""
    import json
    import hybrid
    print("SET", hybrid.use_cpu_cores(3))
    hybrid.use_quick_compiles()  # as the `hybrid` command does after its device count
    import jax
    jax.config.update("jax_enable_x64", True)
    import numpy as np
    from hybrid.core._levenberg_marquardt import LMSettings
    from hybrid.discovery import _search as search
    from hybrid.core._devices import spread_devices
    from hybrid.discovery._diagnosis import DiagnoseSettings

    rng = np.random.default_rng(3)
    n, dt = 400, 1 / 30
    v = np.repeat(rng.uniform(-1, 1, n // 20), 20)
    y = np.zeros(n)
    for k in range(1, n):  # a first-order lag, made here in numpy
        y[k] = 0.8 * y[k - 1] + 0.2 * v[k - 1]
    w = 2.0 * np.tanh(y) + 0.01 * rng.standard_normal(n)
    recording = hybrid.Recording.from_arrays(np.arange(n) * dt, v, w)
    simulation = hybrid.LTI(1)
    settings = DiagnoseSettings()
    problem, n_rows, model = search.lanes_problem([recording], simulation, settings, ["saturation"])
    frozen = frozenset(settings.frozen_for(simulation))
    theta = np.asarray(search.initial_theta(problem, model.simulation, model.readout, frozen))
    thetas = np.stack([theta * (1.0 + 0.5 * k) for k in range(5)])  # five starts far enough apart to end apart
    actives = np.ones((5, len(model.simulation.effects)))
    actives[::2, 0] = 0.0  # saturation on in lanes 1 and 3 only
    tangents = np.stack(
        [search.lane_tangents(model, frozen, "saturation" if a[0] else None, n_rows) for a in actives]
    )
    lm = LMSettings(max_steps=30)
    sharded = search.fit_lanes(problem, actives, tangents, thetas, lm, 10)
    single = jax.device_get(
        search._fit_lanes_compiled(
            problem, actives, tangents, search._start_states(thetas), np.ones(5, bool), np.int32(10),
            np.int32(lm.max_steps), lm,
        )
    )
    # Stopped at a patience of 3, then those the patience stopped resumed to 10 (`resume`).
    short = search.fit_lanes(problem, actives, tangents, thetas, lm, 3)
    stopped = np.flatnonzero((short.since_best >= 3) & (short.step < lm.max_steps))
    resumed = search.fit_lanes(problem, actives, tangents, search.resume(short, stopped), lm, 10)
    # Capped at 3 steps (`steps`), then every lane the cap stopped resumed to the same patience.
    capped = search.fit_lanes(problem, actives, tangents, thetas, lm, 10, steps=3)
    going = np.flatnonzero(~capped.done)
    uncapped = search.fit_lanes(problem, actives, tangents, search.resume(capped, going), lm, 10)
    print(json.dumps({
        "devices": len(jax.devices()),
        "used": len(spread_devices()),
        "sharded_val": np.asarray(sharded.best_val).tolist(),
        "single_val": np.asarray(single.best_val).tolist(),
        "sharded_theta": np.asarray(sharded.best_theta).tolist(),
        "single_theta": np.asarray(single.best_theta).tolist(),
        "sharded_steps": np.asarray(sharded.step).tolist(),
        "single_steps": np.asarray(single.step).tolist(),
        "short_steps": np.asarray(short.step).tolist(),
        "resumed": len(stopped),
        "resumed_val": np.asarray(resumed.best_val).tolist(),
        "resumed_theta": np.asarray(resumed.best_theta).tolist(),
        "resumed_steps": np.asarray(resumed.step).tolist(),
        "capped_steps": np.asarray(capped.step).tolist(),
        "uncapped_val": np.asarray(uncapped.best_val).tolist(),
        "uncapped_theta": np.asarray(uncapped.best_theta).tolist(),
        "uncapped_steps": np.asarray(uncapped.step).tolist(),
    }))
""")


SCREENS = textwrap.dedent("""
    import json, sys
    import hybrid
    hybrid.use_cpu_cores(int(sys.argv[1]))
    hybrid.use_quick_compiles()
    import jax
    jax.config.update("jax_enable_x64", True)
    import numpy as np
    from hybrid.core import _screen as screen
    from hybrid.discovery import _search as search, _starts as starts
    from hybrid.discovery._diagnosis import DiagnoseSettings

    rng = np.random.default_rng(4)
    n, dt = 300, 1 / 30
    v = np.repeat(rng.uniform(-1, 1, n // 15), 15)
    w = np.convolve(v, 0.3 * 0.7 ** np.arange(30))[:n] + 0.01 * rng.standard_normal(n)
    recording = hybrid.Recording.from_arrays(np.arange(n) * dt, v, w)
    simulation = hybrid.LTI(1)
    problem, *_ = search.lanes_problem([recording], simulation, DiagnoseSettings(), ["saturation"])
    design = screen.start_design(simulation, 40)
    _, raws = screen.design_raws(simulation, design)
    loop = starts.loop_screen(problem, simulation, raws, starts.LOOP_RATES)
    modes = starts.mode_screen(problem, simulation, raws, np.array([2.0, 5.0]), np.array([0.1, 0.3]))
    print(json.dumps({
        "devices": len(jax.devices()),
        "losses": screen.screen_design_losses(problem, simulation, raws).tolist(),
        "loop": [np.asarray(x).tolist() for x in loop],
        "modes": np.asarray(modes).tolist(),
        "peaks": np.asarray(starts.state_peaks(problem, simulation, "lag_1", raws)).tolist(),
    }))
""")


def _python(code, *args, **env):
    return subprocess.run(
        [sys.executable, "-c", code, *args],
        capture_output=True,
        text=True,
        env={**{k: v for k, v in os.environ.items() if k not in ("JAX_NUM_CPU_DEVICES", "XLA_FLAGS")}, **env},
    )


def test_lanes_on_three_cpu_devices_equal_the_lanes_on_one():
    proc = _python(LANES, JAX_PLATFORMS="cpu")
    assert proc.returncode == 0, proc.stderr[-3000:]
    lines = proc.stdout.strip().splitlines()
    assert lines[0] == "SET 3"
    out = json.loads(lines[-1])
    assert out["devices"] == 3 and out["used"] == 3
    # every lane moved (else the comparison would be of starts), and the lanes differ from each other
    assert min(out["single_steps"]) > 0
    assert len({round(v, 12) for v in out["single_val"]}) == 5
    assert out["sharded_steps"] == out["single_steps"]
    # the same program on each device's share: equal to rounding (measured ≤ 1e-15 relative)
    for a, b in zip(out["sharded_val"], out["single_val"]):
        assert a == pytest.approx(b, rel=1e-10)
    for a, b in zip(out["sharded_theta"], out["single_theta"]):
        assert a == pytest.approx(b, rel=1e-8, abs=1e-10)
    # A lane stopped by a short patience and resumed takes the steps the longer patience takes from
    # the start (`resume`: LM's whole state goes on), the same arithmetic: equal to the last bit.
    assert out["resumed"] > 0 and out["short_steps"] != out["sharded_steps"]
    assert out["resumed_steps"] == out["sharded_steps"]
    assert out["resumed_val"] == out["sharded_val"]
    assert out["resumed_theta"] == out["sharded_theta"]
    # So does a lane capped at 3 LM steps (`fit_lanes`' `steps`, as the race's first round) and resumed.
    assert max(out["capped_steps"]) == 3 and max(out["sharded_steps"]) > 3
    assert out["uncapped_steps"] == out["sharded_steps"]
    assert out["uncapped_val"] == out["sharded_val"]
    assert out["uncapped_theta"] == out["sharded_theta"]


def test_the_screens_on_three_cpu_devices_equal_the_screens_on_one():
    runs = {}
    for devices in (3, 1):
        proc = _python(SCREENS, str(devices), JAX_PLATFORMS="cpu")
        assert proc.returncode == 0, proc.stderr[-3000:]
        runs[devices] = json.loads(proc.stdout.strip().splitlines()[-1])
    assert runs[3]["devices"] == 3 and runs[1]["devices"] == 1
    assert len(runs[3]["losses"]) == 40 and len(set(runs[3]["losses"])) > 30  # 40 points, not one repeated
    for key in ("losses", "loop", "modes", "peaks"):  # measured: equal to the last bit
        np.testing.assert_allclose(np.asarray(runs[3][key]), np.asarray(runs[1][key]), rtol=1e-12, atol=0)


def test_a_device_count_chosen_outside_the_script_wins():
    code = "import hybrid, jax; print(hybrid.use_cpu_cores(4), len(jax.devices()))"
    chosen = _python(code, JAX_NUM_CPU_DEVICES="1", JAX_PLATFORMS="cpu")
    assert chosen.returncode == 0, chosen.stderr[-2000:]
    assert chosen.stdout.split() == ["None", "1"]
    flags = _python(code, XLA_FLAGS="--xla_force_host_platform_device_count=2", JAX_PLATFORMS="cpu")
    assert flags.returncode == 0, flags.stderr[-2000:]
    assert flags.stdout.split() == ["None", "2"]
    free = _python(code, JAX_PLATFORMS="cpu")
    assert free.returncode == 0, free.stderr[-2000:]
    assert free.stdout.split() == ["4", "4"]
    late = _python("import hybrid, jax; jax.devices(); print(hybrid.use_cpu_cores(4), len(jax.devices()))")
    assert late.returncode == 0, late.stderr[-2000:]
    assert late.stdout.split()[0] == "None"  # the backend had started: nothing changes
