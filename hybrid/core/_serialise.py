"""Save and load models: Equinox serialisation of the arrays + JSON metadata.

A model saved to ``path`` is two files: ``path`` (the leaves, written by
`eqx.tree_serialise_leaves`) and ``path.json`` (what is needed to rebuild the
skeleton: model kind, the simulation's class and its `config()`, readout shape; plus the
fitted parameters in physical units and, when saved from a fit, its metrics).

Both files are written together and atomically ([`hybrid.util._atomic.staged`][]):
a failed save (a full disk) leaves a model already at ``path`` as it was. The
leaves go through an open file, so ``path`` is used exactly as given (Equinox
would append ``.eqx`` to a path without that suffix).
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import equinox as eqx
import jax
import numpy as np

from ..util._atomic import staged
from ..util._errors import InputError
from ._models import Model
from ._readout import LinearReadout, WindowedMLP
from ._simulation import AbstractSimulation

FORMAT = "hybrid-model/1"


def describe_simulation(sim: AbstractSimulation) -> dict:
    """The simulation's skeleton: its class (name and module) and its `config()`."""
    return {"type": type(sim).__qualname__, "module": type(sim).__module__, "config": sim.config()}


def build_simulation(description: dict) -> AbstractSimulation:
    """A simulation with default parameters from `describe_simulation`'s dict (its class imported)."""
    cls = simulation_class(description["type"], description.get("module"))
    # Files saved before `config` was recorded hold the RC network's settings at the top level.
    config = (
        description["config"]
        if "config" in description
        else {k: v for k, v in description.items() if k not in ("type", "module")}
    )
    return cls.from_config(config)


def _describe(model: Model) -> dict:
    sim, readout = model.simulation, model.readout
    simulation = describe_simulation(sim)
    if isinstance(readout, WindowedMLP):
        if readout.mlp.activation is not jax.numpy.tanh:
            raise InputError("only tanh D-MLPs can be saved")
        out = {
            "type": "WindowedMLP",
            "window": readout.window,
            "depth": len(readout.mlp.layers) - 1,
            "width": readout.mlp.width_size,
        }
    elif isinstance(readout, LinearReadout):
        out = {"type": "LinearReadout"}
    else:
        raise InputError(f"cannot save a model with readout {type(readout).__name__}")
    return {
        "format": FORMAT,
        "kind": model.kind,
        "simulation": simulation,
        "readout": out,
        "signal_units": dict(zip(("w", "v_in"), model.signal_units)),
    }


def subclasses(cls) -> list[type]:
    """Every imported subclass of `cls`, at any depth (a saved model names its classes among these)."""
    out = []
    for sub in cls.__subclasses__():
        out += [sub, *subclasses(sub)]
    return out


def imported_class(base: type, name: str, module: str | None, what: str) -> type:
    """The imported subclass of `base` saved as `module:name` (or only `name`, if unique).

    Only classes already imported are candidates: loading a model never imports
    code named in a file. `what` names the kind in messages ("simulation").
    """
    found = [c for c in subclasses(base) if c.__qualname__ == name]
    exact = [c for c in found if c.__module__ == module]
    if exact or len(found) == 1:
        return (exact or found)[0]
    where = f" (module {module})" if module else ""
    if not found:
        plugin = re.fullmatch(r"hybrid_plugin_(.+)_[0-9a-f]+", module or "")
        hint = (  # a class from a plug-in file (hybrid_plugin_<stem>_<digest>): the flag that loads it
            f"; it came from a plug-in file {plugin.group(1)}.py: on the command line give "
            f"--physics path/to/{plugin.group(1)}.py:{name.split('.')[0]} (or --effects for an effect)"
            if plugin
            else ""
        )
        raise InputError(
            f"the model's {what} {name}{where} is not an imported {base.__name__}: import the "
            f"module that defines it before load_model{hint}"
        )
    raise InputError(
        f"several imported {what}s are called {name} ({', '.join(c.__module__ for c in found)}): "
        "import only the one the model was saved with"
    )


def simulation_class(name: str, module: str | None = None) -> type[AbstractSimulation]:
    """The imported `AbstractSimulation` subclass saved as `module:name` (`imported_class`).

    A model saved before the module was recorded names only the class.
    """
    return imported_class(AbstractSimulation, name, module, "simulation")


def _skeleton(description: dict) -> Model:
    out_d = description["readout"]
    simulation = build_simulation(description["simulation"])
    readout: WindowedMLP | LinearReadout
    if out_d["type"] == "WindowedMLP":
        readout = WindowedMLP(out_d["window"], out_d["depth"], out_d["width"], key=jax.random.key(0))
    else:
        readout = LinearReadout()
    units = description.get("signal_units") or {}  # a model saved before units were kept: the paper's
    return Model(
        simulation, readout, description["kind"], (str(units.get("w", "mm")), str(units.get("v_in", "V")))
    )


def _path(path, where: str) -> Path:
    if not isinstance(path, (str, os.PathLike)) or not str(path).strip():
        raise InputError(
            f"{where} needs a file path (str or pathlib.Path), got {path!r}: give e.g. 'fit.eqx'"
        )
    return Path(path)


def save_model(path, model: Model, extra: dict | None = None) -> Path:
    """Write `model` to `path` (+ `path.json`); `extra` (JSON-able) is stored alongside.

    Both files are replaced together only once both are written whole.
    """
    path = _path(path, "save_model")
    if not isinstance(model, Model):
        raise InputError(
            f"save_model needs a hybrid.Model (e.g. FitResult.model), got {type(model).__name__}"
        )
    if path.is_dir():
        raise InputError(
            f"cannot save a model to {path}: it is a folder; give a file name such as {path / 'fit.eqx'}"
        )
    description = _describe(model)
    description["parameters"] = {k: float(v) for k, v in model.parameters().items()}
    description["units"] = model.units
    if extra:
        description["extra"] = extra
    try:
        text = json.dumps(description, indent=2, allow_nan=False)
    except (TypeError, ValueError) as error:
        raise InputError(
            f"save_model: extra is not JSON-able ({error}): use dicts, lists, strings, "
            "finite numbers, booleans and None"
        ) from None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise InputError(
            f"cannot create the folder {path.parent} for {path} ({error.strerror or error}): create it or choose another path"
        ) from None
    with staged(path, Path(f"{path}.json")) as (leaves, meta):
        with open(leaves, "wb") as handle:
            eqx.tree_serialise_leaves(handle, model)
        meta.write_text(text + "\n", encoding="utf-8")
    return path


def load_model(path) -> Model:
    """Read a model written by [`save_model`][]."""
    path = _path(path, "load_model")
    meta = Path(f"{path}.json")
    if not path.is_file() or not meta.is_file():
        raise InputError(
            f"model file {path} or its metadata {meta} is missing: save it with `hybrid fit --out`"
        )
    try:
        description = json.loads(meta.read_text())
    except json.JSONDecodeError as error:
        raise InputError(f"model metadata {meta} is not valid JSON ({error})") from None
    if not isinstance(description, dict) or description.get("format") != FORMAT:
        found = description.get("format") if isinstance(description, dict) else type(description).__name__
        raise InputError(f"{meta} is not a hybrid model description (format {found!r})")
    try:
        skeleton = _skeleton(description)
    except (KeyError, TypeError, AttributeError) as error:
        raise InputError(
            f"model metadata {meta} is incomplete ({type(error).__name__}: {error}): "
            "save the model again with save_model or `hybrid fit --out`"
        ) from None
    try:
        with open(path, "rb") as handle:
            model = eqx.tree_deserialise_leaves(handle, skeleton)
    except Exception as error:  # equinox raises several types for a mismatched file
        raise InputError(f"model file {path} does not match its metadata ({error})") from None
    # The metadata's parameters must be what the weights give: catches a file
    # paired with another model's metadata (or an edited N, which lives only there).
    expected = description.get("parameters", {})
    for name, value in model.parameters().items():
        if name in expected and not np.isclose(float(value), expected[name], rtol=1e-9, atol=0):
            if not jax.config.read("jax_enable_x64") and np.isclose(
                float(value), expected[name], rtol=1e-6, atol=0
            ):
                raise InputError(
                    f"model file {path} holds float64 weights and this session runs float32: call "
                    "jax.config.update('jax_enable_x64', True) before load_model (the CLI does)"
                )
            raise InputError(
                f"model file {path} does not match its metadata: {name} is {float(value):.6g} in the "
                f"weights but {expected[name]:.6g} in {meta}"
            )
    return model
