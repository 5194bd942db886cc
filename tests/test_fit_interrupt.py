"""A fit stopped early keeps its best model: `fit(stop=...)`, `hybrid fit --time-limit`, SIGTERM mid-fit.

Cheap on purpose: the normal model (a D-MLP 1 × 3 on a 5-sample window, 22
weights) on a 20 s recording at 30 Hz (600 samples), a few steps. Nothing
here depends on wall time: the time limit is 1 ns (it has passed when the fit
first looks, after its start is evaluated), and "mid-fit" for SIGTERM is read
from the command's own heartbeat on stderr, which names the step it is at.
"""

import json
import os
import signal
import subprocess
import sys

import helpers as h
import jax
import numpy as np
import pytest

from hybrid import LevenbergMarquardt, Recording, fit, load_model, make_model
from hybrid.cli import main

TINY = dict(window=5, depth=1, width=3)
TINY_ARGS = ["--model", "normal", "--window", "5", "--depth", "1", "--width", "3"]
N = 600


def _recording() -> Recording:
    v = h.step_drive(N, seed=2)
    kernel = np.exp(-np.arange(30) / 6.0) / 6.0
    w = np.tanh(np.convolve(v, kernel)[:N]) + 0.01 * np.random.default_rng(2).normal(size=N)
    return Recording(t=np.arange(N) / h.RATE, v_in=v, w=w)


def _validation_mse(model, recording) -> float:
    """Mean squared error on the validation split (the last 20 %), from the model's own prediction."""
    _, _, (a, b) = h.split_bounds(recording.n)
    w_hat = np.asarray(model.predict(recording.v_in, recording.dt, ((a, b),)))
    return float(np.mean((recording.w[a:b] - w_hat) ** 2))


def _prediction(model, recording):
    return np.asarray(model.predict(recording.v_in, recording.dt, ((0, recording.n),)))


def test_lm_stopped_after_two_steps_is_the_fit_of_two_steps():
    recording = _recording()
    model = make_model("normal", key=jax.random.key(0), **TINY)
    looks = []

    def stop():  # looked at before each LM step: true before the third
        looks.append(None)
        return len(looks) == 3

    stopped = fit(model, recording, solver=LevenbergMarquardt(max_steps=50), progress=False, stop=stop)
    assert stopped.stopped and stopped.to_dict()["stopped"]
    assert stopped.starts[0]["steps"] == 2
    reference = fit(
        model, recording, solver=LevenbergMarquardt(max_steps=2), progress=False
    )  # the same two steps, run to the end
    assert not reference.stopped and reference.starts[0]["steps"] == 2
    ours, theirs = _prediction(stopped.model, recording), _prediction(reference.model, recording)
    assert np.max(np.abs(ours - theirs)) <= 1e-12 * np.max(np.abs(theirs))
    start = fit(
        model, recording, solver=LevenbergMarquardt(max_steps=50), progress=False, stop=lambda: True
    )  # stopped before any step
    assert start.stopped and start.starts[0]["steps"] == 0
    assert stopped.starts[0]["validation_loss"] <= start.starts[0]["validation_loss"]
    assert _validation_mse(stopped.model, recording) <= _validation_mse(start.model, recording)


@pytest.fixture(scope="module")
def stopped_at_start(tmp_path_factory):
    """`hybrid fit --time-limit 1e-9` over an existing --out: (folder, recording, exit code, stderr)."""
    folder = tmp_path_factory.mktemp("time_limit")
    recording = _recording()
    recording.save(folder / "rec.csv")
    (folder / "m.eqx").write_bytes(b"the user's model")
    (folder / "m.eqx.json").write_text('{"mine": true}\n')
    argv = [
        "fit",
        str(folder / "rec.csv"),
        *TINY_ARGS,
        "--time-limit",
        "1e-9",
        "--quiet",
        "--out",
        str(folder / "m.eqx"),
    ]
    with pytest.raises(SystemExit) as stopped:
        main(argv)
    return folder, recording, stopped.value.code


def test_time_limit_saves_the_best_model_so_far_beside_out(stopped_at_start, capsys):
    folder, recording, code = stopped_at_start
    assert code == 124
    assert (folder / "m.eqx").read_bytes() == b"the user's model"  # --out untouched
    assert (folder / "m.eqx.json").read_text() == '{"mine": true}\n'
    model = load_model(folder / "m.partial.eqx")
    meta = json.loads((folder / "m.partial.eqx.json").read_text())
    assert meta["extra"]["stopped"] == "--time-limit" and meta["extra"]["steps"] == 0
    # no step was taken: the partial model is the start, scored as fit scored it
    assert np.isfinite(_validation_mse(model, recording))
    assert not list(folder.glob("*.lock")) and not list(folder.glob(".*.tmp*"))


def test_sigterm_mid_fit_saves_the_best_model_so_far(stopped_at_start, tmp_path):
    _, recording, _ = stopped_at_start
    start = load_model(stopped_at_start[0] / "m.partial.eqx")  # the same start: same data, seed and sizes
    recording.save(tmp_path / "rec.csv")
    out = tmp_path / "m.eqx"
    out.write_bytes(b"the user's model")
    env = dict(os.environ, HYBRID_HEARTBEAT_S="0.2")  # a heartbeat line, naming the step, every 0.2 s
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "hybrid.cli",
            "fit",
            str(tmp_path / "rec.csv"),
            *TINY_ARGS,
            "--solver",
            "adam",
            "--max-steps",
            "1000000",
            "--out",
            str(out),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    seen = []
    for line in proc.stderr:  # Adam never ends by itself in 10⁶ steps here: it is mid-fit when we signal
        seen.append(line)
        if "fit: Adam on the normal model, step" in line:
            break
    else:
        pytest.fail(f"no progress line before the command ended: {''.join(seen)[-500:]}")
    proc.send_signal(signal.SIGTERM)
    _, rest = proc.communicate(timeout=600)  # a guard against a hang only: the command ends in seconds
    assert proc.returncode == 143, rest
    told = [line for line in rest.splitlines() if "saved the best model so far" in line]
    assert len(told) == 1 and "SIGTERM" in told[0] and "m.partial.eqx" in told[0]
    assert out.read_bytes() == b"the user's model"
    partial = load_model(tmp_path / "m.partial.eqx")
    meta = json.loads((tmp_path / "m.partial.eqx.json").read_text())
    assert meta["extra"]["stopped"] == "SIGTERM" and meta["extra"]["steps"] >= 10
    assert _validation_mse(partial, recording) <= _validation_mse(start, recording)
