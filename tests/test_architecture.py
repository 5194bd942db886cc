"""The house's shape: which room may import which, and one meaning for a leading `_` (private to its module).

Imports are read from the source (every `import` statement, at module level or
inside a function), so a lazy import cannot hide a dependency that points the
wrong way.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: Each sub-package of `hybrid` and the sub-packages it may import. The layers,
#: bottom up: util ← data ← core ← physics, sensitivity ← discovery ← ipmc.
#: `hybrid/__init__.py` and `hybrid/cli.py` (the entry points) may import any.
ALLOWED = {
    "util": set(),
    "data": {"util"},
    "core": {"util", "data"},
    "physics": {"util", "data", "core"},
    "sensitivity": {"util", "data", "core"},
    "discovery": {"util", "data", "core", "sensitivity"},
    "ipmc": {"util", "data", "core", "physics", "sensitivity", "discovery"},
}

#: Where the one-meaning-of-`_` rule holds: the packages and the code that uses them as a user would.
USERS = ("hybrid", "rig", "experiments", "examples", "benchmarks")


def _modules(package: str) -> list[Path]:
    return sorted((ROOT / package).rglob("*.py"))


def _dotted(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _is_module(name: str) -> bool:
    path = ROOT.joinpath(*name.split("."))
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def imported_modules(path: Path) -> set[str]:
    """Absolute names of everything `path` imports (relative imports resolved)."""
    module = _dotted(path)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            out.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module
            for alias in node.names:  # `from package import module` imports the module, not all of package
                candidate = f"{target}.{alias.name}"
                out.add(candidate if _is_module(candidate) else target)
    return out


def _room(name: str) -> str | None:
    """The sub-package of hybrid that module `name` belongs to, "" for hybrid itself, None outside."""
    parts = name.split(".")
    if parts[0] != "hybrid":
        return None
    return parts[1] if len(parts) > 1 and parts[1] in ALLOWED else ""


def test_every_room_of_hybrid_is_declared():
    packages = {p.parent.name for p in (ROOT / "hybrid").glob("*/__init__.py")}
    assert packages == set(ALLOWED)


@pytest.mark.parametrize("path", _modules("hybrid"), ids=lambda p: str(p.relative_to(ROOT)))
def test_imports_point_down(path):
    room = _room(_dotted(path))
    if room == "":  # hybrid/__init__.py and hybrid/cli.py: the entry points
        assert not any(name.split(".")[0] == "rig" for name in imported_modules(path))
        return
    wrong = []
    for name in sorted(imported_modules(path)):
        if name.split(".")[0] == "rig":
            wrong.append(f"{name} (hybrid never imports the rig)")
            continue
        target = _room(name)
        if target is None or target == room:
            continue
        if target == "":  # hybrid itself or hybrid.cli: that would import every room
            wrong.append(f"{name} (a room imports rooms, not the package front)")
        elif target not in ALLOWED[room]:
            wrong.append(f"{name} ({room} may import only {sorted(ALLOWED[room]) or 'nothing of hybrid'})")
    assert not wrong, f"{path.relative_to(ROOT)} imports against the layers: " + "; ".join(wrong)


def test_generic_rooms_never_name_a_physics():
    """core, data, discovery and sensitivity work with any simulation: none imports one by name."""
    for room in ("util", "data", "core", "sensitivity", "discovery"):
        for path in _modules(f"hybrid/{room}"):
            physics = sorted(n for n in imported_modules(path) if _room(n) in ("physics", "ipmc"))
            assert not physics, f"{path.relative_to(ROOT)} imports {physics}"


def test_the_checker_sees_lazy_and_relative_imports(tmp_path, monkeypatch):
    """The import reader resolves `..` and finds imports inside functions (else the layer test could not fail)."""
    package = tmp_path / "hybrid" / "core"
    package.mkdir(parents=True)
    source = package / "_probe.py"
    (package / "_fit.py").write_text("")
    source.write_text("def f():\n    from ..physics._rc_network import RCNetwork\n    from . import _fit\n")
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    names = imported_modules(source)
    assert names == {"hybrid.physics._rc_network", "hybrid.core._fit"}


def private_crossings(paths) -> list[str]:
    """Where a private (`_`) name crosses a module border in `paths`.

    - `from X import _name` where `_name` is not a module of X's package (a private module imported
      inside its own package, `from . import _residual`, is allowed; its *names* are not);
    - `alias._name` where `alias` was bound by `import X as alias` / `from P import X as alias` to a
      module of hybrid or rig;
    - `hybrid._x`/`rig._x` modules imported from outside their own top-level package (examples,
      experiments and benchmarks use only the public names the packages export).
    """
    found = []
    for path in paths:
        rel = path.relative_to(ROOT)
        tree = ast.parse(path.read_text())
        aliases = {}
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                base = path.parent
                for _ in range(max(node.level - 1, 0)):
                    base = base.parent
                where = (
                    base.joinpath(*(node.module or "").split("."))
                    if node.level
                    else ROOT.joinpath(*(node.module or "").split("."))
                )
                parts = (node.module or "").split(".")
                if (
                    not node.level
                    and parts[0] in ("hybrid", "rig")
                    and parts[0] != rel.parts[0]
                    and any(p.startswith("_") for p in parts[1:])
                ):
                    found.append(f"{rel}:{node.lineno}: private module {node.module}")
                for alias in node.names:
                    is_module = (where / f"{alias.name}.py").exists() or (where / alias.name).is_dir()
                    if is_module:
                        aliases[alias.asname or alias.name] = alias.name
                    if alias.name.startswith("_") and not alias.name.startswith("__") and not is_module:
                        found.append(f"{rel}:{node.lineno}: {alias.name}")
            elif isinstance(node, ast.Import):
                for alias in node.names:
                    parts = alias.name.split(".")
                    if parts[0] in ("hybrid", "rig") and alias.asname:
                        aliases[alias.asname] = alias.name
                    if (
                        parts[0] in ("hybrid", "rig")
                        and parts[0] != rel.parts[0]
                        and any(p.startswith("_") and not p.startswith("__") for p in parts[1:])
                    ):
                        found.append(f"{rel}:{node.lineno}: private module {alias.name}")
        for node in ast.walk(tree):
            if (
                isinstance(node, ast.Attribute)
                and isinstance(node.value, ast.Name)
                and node.value.id in aliases
                and node.attr.startswith("_")
                and not node.attr.startswith("__")
            ):
                found.append(f"{rel}:{node.lineno}: {node.value.id}.{node.attr}")
    return found


def test_no_private_name_crosses_a_module_border():
    """One meaning for `_`: private to its module. A name another module uses is public in its module
    (the module itself may be private and re-exported from its package), as in optimistix and diffrax."""
    found = private_crossings([p for top in USERS for p in _modules(top)])
    assert not found, "private names used across modules (make them public where they live):\n" + "\n".join(
        found
    )


def test_the_crossing_check_sees_private_names_modules_and_attributes(tmp_path, monkeypatch):
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "_mod.py").write_text("_x = 1\n")
    source = tmp_path / "pkg" / "user.py"
    source.write_text("from . import _mod\nfrom ._mod import _x\nprint(_mod._x)\n")
    (tmp_path / "experiments").mkdir()
    outside = tmp_path / "experiments" / "run.py"
    outside.write_text("from hybrid.core._fit import fit\n")
    assert private_crossings([source, outside]) == [
        "pkg/user.py:2: _x",
        "pkg/user.py:3: _mod._x",
        "experiments/run.py:1: private module hybrid.core._fit",
    ]


def test_importing_hybrid_leaves_scipy_and_optax_to_the_functions_that_use_them():
    """`import hybrid` is every command's first second: scipy.signal, scipy.stats, scipy.optimize and
    optax took 1–2 s of a 2.7 s import, for functions most commands never call (measured with
    ``python -X importtime -c "import hybrid"``). They are imported where they are used."""
    import subprocess

    heavy = ("scipy.signal", "scipy.stats", "scipy.optimize", "scipy.linalg", "optax")
    code = f"import sys, hybrid, hybrid.cli; print([m for m in {heavy!r} if m in sys.modules])"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip() == "[]", proc.stdout
