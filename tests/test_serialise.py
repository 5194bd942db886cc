"""save_model / load_model: exact round trips and clear errors."""

import json
from typing import ClassVar

import equinox as eqx
import helpers as h
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from hybrid import (
    AbstractSimulation,
    InputError,
    LinearReadout,
    Model,
    RCNetwork,
    Strip,
    WindowedMLP,
    load_model,
    make_model,
    save_model,
)

DT = 1 / 30
V = h.step_drive(120, seed=7)


@eqx.filter_jit
def _predict(model):
    return model.predict(V, DT)


def _models():
    strip = Strip(length=30e-3, width=4e-3)
    sim = RCNetwork(
        xi_rho=7.0,
        xi_h=0.8,
        alpha_E=0.3,
        alpha_I=0.7,
        alpha_C=0.45,
        C_clamp=0.02,
        strip=strip,
        n_stages=6,
        method="zoh",
    )
    hybrid = make_model("hybrid", simulation=sim, window=5, depth=2, width=4, key=jax.random.key(5))
    # non-default fixed scalings must survive too
    hybrid = eqx.tree_at(lambda m: m.readout.scales, hybrid, jnp.array([0.1, 2.0, -0.3, 0.7]))
    normal = make_model("normal", window=4, depth=1, width=3, key=jax.random.key(6))
    physics = Model(RCNetwork(n_stages=4), LinearReadout(gain=2.5, offset=-0.125), "physics")
    return {"hybrid": hybrid, "normal": normal, "physics": physics}


@pytest.mark.parametrize("kind", ["hybrid", "normal", "physics"])
def test_round_trip_is_exact(tmp_path, kind):
    model = _models()[kind]
    path = save_model(tmp_path / "sub" / f"{kind}.eqx", model, extra={"note": "test", "nmse": 1e-3})
    assert path.is_file() and (tmp_path / "sub" / f"{kind}.eqx.json").is_file()
    loaded = load_model(path)
    assert loaded.kind == kind
    assert type(loaded.simulation) is type(model.simulation)
    assert type(loaded.readout) is type(model.readout)
    # every array leaf identical, bit for bit
    a = jax.tree_util.tree_leaves(eqx.filter(model, eqx.is_array))
    b = jax.tree_util.tree_leaves(eqx.filter(loaded, eqx.is_array))
    assert len(a) == len(b) > 0
    assert all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(a, b))
    # and so the predictions
    np.testing.assert_array_equal(np.asarray(_predict(loaded)), np.asarray(_predict(model)))
    if isinstance(model.simulation, RCNetwork):
        assert loaded.simulation.strip == model.simulation.strip
        assert loaded.simulation.n_stages == model.simulation.n_stages
        assert loaded.simulation.method == model.simulation.method


def test_metadata_describes_the_model(tmp_path):
    model = _models()["physics"]
    path = save_model(tmp_path / "physics.eqx", model, extra={"metrics": {"test": {"nmse": 0.01}}})
    meta = json.loads((tmp_path / "physics.eqx.json").read_text())
    assert meta["kind"] == "physics"
    assert meta["simulation"]["type"] == "RCNetwork" and meta["simulation"]["config"]["n_stages"] == 4
    assert meta["simulation"]["module"] == "hybrid.physics._rc_network"
    assert meta["readout"] == {"type": "LinearReadout"}
    expected = {
        "xi_rho": 10.0,
        "xi_h": 1.0,
        "alpha_E": 0.5,
        "alpha_I": 0.5,
        "alpha_C": 0.5,
        "C_clamp": 0.05,
        "gain": 2.5,
        "offset": -0.125,
    }
    assert meta["parameters"] == pytest.approx(expected, rel=1e-13)
    assert meta["units"]["C_clamp"] == "F" and meta["units"]["gain"] == "mm/V"
    assert meta["extra"] == {"metrics": {"test": {"nmse": 0.01}}}
    assert path == tmp_path / "physics.eqx"


def test_hybrid_metadata_has_readout_shape(tmp_path):
    save_model(tmp_path / "m", _models()["hybrid"])
    meta = json.loads((tmp_path / "m.json").read_text())
    assert meta["readout"] == {"type": "WindowedMLP", "window": 5, "depth": 2, "width": 4}
    assert meta["simulation"]["config"]["method"] == "zoh"
    assert meta["simulation"]["config"]["strip"]["length"] == pytest.approx(30e-3, rel=1e-15)
    assert meta["parameters"]["xi_rho"] == pytest.approx(7.0, rel=1e-13)


def test_missing_files_raise_input_error(tmp_path):
    with pytest.raises(InputError):
        load_model(tmp_path / "nothing.eqx")
    path = save_model(tmp_path / "m.eqx", _models()["physics"])
    (tmp_path / "m.eqx.json").unlink()
    with pytest.raises(InputError):
        load_model(path)


@pytest.mark.parametrize(
    "edit",
    [
        lambda meta: meta["readout"].update(width=5),  # leaves no longer fit the skeleton
        lambda meta: meta["readout"].update(window=7),
        lambda meta: meta.update(format="something-else/2"),
    ],
)
def test_mismatched_metadata_raises_input_error(tmp_path, edit):
    path = save_model(tmp_path / "m.eqx", _models()["hybrid"])
    meta_path = tmp_path / "m.eqx.json"
    meta = json.loads(meta_path.read_text())
    edit(meta)
    meta_path.write_text(json.dumps(meta))
    with pytest.raises(InputError):
        load_model(path)


def test_corrupt_files_raise_input_error(tmp_path):
    path = save_model(tmp_path / "m.eqx", _models()["hybrid"])
    meta_path = tmp_path / "m.eqx.json"
    good = meta_path.read_text()
    meta_path.write_text(good[: len(good) // 2])  # truncated JSON
    with pytest.raises(InputError):
        load_model(path)
    meta_path.write_text(good)
    path.write_bytes(path.read_bytes()[:40])  # truncated leaves
    with pytest.raises(InputError):
        load_model(path)


class _Custom(AbstractSimulation):
    raw: dict
    constraints: ClassVar[dict] = {}
    units: ClassVar[dict] = {}

    def __init__(self):
        self.raw = {}

    def simulate(self, v_in, dt):
        return 2.0 * jnp.asarray(v_in)


class _Configured(_Custom):
    gain: float = eqx.field(static=True)

    def __init__(self, gain=2.0):
        self.raw = {}
        self.gain = gain

    def simulate(self, v_in, dt):
        return self.gain * jnp.asarray(v_in)


def test_a_plug_in_simulation_round_trips(tmp_path):
    """Any imported AbstractSimulation is saved by class and config, and loaded back as that class."""
    custom = Model(_Custom(), LinearReadout(gain=1.5), "custom")
    load = load_model(save_model(tmp_path / "c.eqx", custom))
    assert type(load.simulation) is _Custom and load.kind == "custom"
    assert float(load.readout.parameters()["gain"]) == 1.5
    meta = json.loads((tmp_path / "c.eqx.json").read_text())
    assert meta["simulation"] == {"type": "_Custom", "module": __name__, "config": {}}


def test_legacy_metadata_without_config_still_loads(tmp_path):
    """Models saved before `config` was recorded name the class only and hold N, method and strip at the top."""
    model = _models()["physics"]
    path = save_model(tmp_path / "old.eqx", model)
    meta_path = tmp_path / "old.eqx.json"
    meta = json.loads(meta_path.read_text())
    meta["simulation"] = {"type": "RCNetwork", **meta["simulation"]["config"]}
    meta_path.write_text(json.dumps(meta))
    loaded = load_model(path)
    assert loaded.simulation.n_stages == 4 and loaded.simulation.strip == model.simulation.strip


def test_unsupported_models_cannot_be_saved(tmp_path):
    custom = Model(_Configured(), LinearReadout(), "custom")
    with pytest.raises(InputError, match="define config"):
        save_model(tmp_path / "c.eqx", custom)
    relu = Model(
        RCNetwork(n_stages=3), WindowedMLP(3, 1, 2, activation=jax.nn.relu, key=jax.random.key(0)), "hybrid"
    )
    with pytest.raises(InputError):
        save_model(tmp_path / "r.eqx", relu)
    assert not (tmp_path / "c.eqx").exists() and not (tmp_path / "r.eqx").exists()


def test_load_model_in_a_float32_session_says_to_enable_float64(tmp_path):
    """It used to say 'C_clamp is 0.0132908 in the weights but 0.0132908 in the json'."""
    import subprocess
    import sys

    from hybrid import RCNetwork, make_model, save_model

    path = tmp_path / "m.eqx"
    save_model(path, make_model("physics", simulation=RCNetwork(C_clamp=0.0132908123456789)))
    code = f"from hybrid import load_model\nload_model({str(path)!r})\n"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode != 0
    assert "jax.config.update('jax_enable_x64', True) before load_model" in proc.stderr
