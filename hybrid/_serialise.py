"""Save and load models: Equinox serialisation of the arrays + JSON metadata.

A model saved to ``path`` is two files: ``path`` (the leaves, written by
`eqx.tree_serialise_leaves`) and ``path.json`` (what is needed to rebuild the
skeleton: model kind, simulation class and settings, readout shape; plus the
fitted parameters in physical units and, when saved from a fit, its metrics).
"""

from __future__ import annotations

import json
from pathlib import Path

import equinox as eqx
import jax
import numpy as np

from ._errors import InputError
from ._models import Model
from ._rc_network import RCNetwork
from ._readout import LinearReadout, WindowedMLP
from ._simulation import Passthrough
from ._strip import Strip

FORMAT = "hybrid-model/1"


def _describe(model: Model) -> dict:
    sim, readout = model.simulation, model.readout
    if isinstance(sim, RCNetwork):
        simulation = {"type": "RCNetwork", "n_stages": sim.n_stages, "method": sim.method,
                      "strip": sim.strip.to_dict()}
    elif isinstance(sim, Passthrough):
        simulation = {"type": "Passthrough"}
    else:
        raise InputError(f"cannot save a model with simulation {type(sim).__name__}: "
                         "only RCNetwork and Passthrough are serialisable")
    if isinstance(readout, WindowedMLP):
        if readout.mlp.activation is not jax.numpy.tanh:
            raise InputError("only tanh D-MLPs can be saved")
        out = {"type": "WindowedMLP", "window": readout.window,
               "depth": len(readout.mlp.layers) - 1, "width": readout.mlp.width_size}
    elif isinstance(readout, LinearReadout):
        out = {"type": "LinearReadout"}
    else:
        raise InputError(f"cannot save a model with readout {type(readout).__name__}")
    return {"format": FORMAT, "kind": model.kind, "simulation": simulation, "readout": out}


def _skeleton(description: dict) -> Model:
    sim_d, out_d = description["simulation"], description["readout"]
    if sim_d["type"] == "RCNetwork":
        simulation = RCNetwork(strip=Strip.from_dict(sim_d["strip"]), n_stages=sim_d["n_stages"],
                               method=sim_d["method"])
    else:
        simulation = Passthrough()
    if out_d["type"] == "WindowedMLP":
        readout = WindowedMLP(out_d["window"], out_d["depth"], out_d["width"], key=jax.random.key(0))
    else:
        readout = LinearReadout()
    return Model(simulation, readout, description["kind"])


def save_model(path, model: Model, extra: dict | None = None) -> Path:
    """Write `model` to `path` (+ `path.json`); `extra` (JSON-able) is stored alongside."""
    path = Path(path)
    description = _describe(model)
    description["parameters"] = {k: float(v) for k, v in model.parameters().items()}
    description["units"] = model.units
    if extra:
        description["extra"] = extra
    path.parent.mkdir(parents=True, exist_ok=True)
    eqx.tree_serialise_leaves(path, model)
    Path(f"{path}.json").write_text(json.dumps(description, indent=2))
    return path


def load_model(path) -> Model:
    """Read a model written by [`save_model`][]."""
    path = Path(path)
    meta = Path(f"{path}.json")
    if not path.is_file() or not meta.is_file():
        raise InputError(f"model file {path} or its metadata {meta} is missing: save it with `hybrid fit --out`")
    try:
        description = json.loads(meta.read_text())
    except json.JSONDecodeError as error:
        raise InputError(f"model metadata {meta} is not valid JSON ({error})") from None
    if description.get("format") != FORMAT:
        raise InputError(f"{meta} is not a hybrid model description (format {description.get('format')!r})")
    skeleton = _skeleton(description)
    try:
        model = eqx.tree_deserialise_leaves(path, skeleton)
    except Exception as error:  # equinox raises several types for a mismatched file
        raise InputError(f"model file {path} does not match its metadata ({error})") from None
    # The metadata's parameters must be what the weights give: catches a file
    # paired with another model's metadata (or an edited N, which lives only there).
    expected = description.get("parameters", {})
    for name, value in model.parameters().items():
        if name in expected and not np.isclose(float(value), expected[name], rtol=1e-9, atol=0):
            raise InputError(
                f"model file {path} does not match its metadata: {name} is {float(value):.6g} in the "
                f"weights but {expected[name]:.6g} in {meta}"
            )
    return model
