"""Style is kept by tools, not by review: ruff (format, import order, lint) and mypy, as configured in
pyproject.toml, over the whole tree. Each check also proves that it can fail."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _run(*args, cwd=ROOT) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", *args], cwd=cwd, capture_output=True, text=True)


def test_ruff_lint_and_format_are_clean():
    lint = _run("ruff", "check", "--no-cache", ".")
    assert lint.returncode == 0, lint.stdout + lint.stderr
    fmt = _run("ruff", "format", "--no-cache", "--check", ".")
    assert fmt.returncode == 0, "run `ruff format .`:\n" + fmt.stdout + fmt.stderr


def test_ruff_sees_an_unsorted_import_and_an_unused_one(tmp_path):
    """The project's configuration (isort and pyflakes rules on) is the one ruff reads."""
    probe = tmp_path / "probe.py"
    probe.write_text("import sys\nimport os\n")
    lint = _run(
        "ruff",
        "check",
        "--no-cache",
        "--config",
        str(ROOT / "pyproject.toml"),
        "--output-format",
        "concise",
        str(probe),
    )
    assert lint.returncode == 1
    assert "I001" in lint.stdout and "F401" in lint.stdout


def test_mypy_is_clean(tmp_path):
    checked = _run("mypy", "--cache-dir", str(tmp_path / "cache"))
    assert checked.returncode == 0, checked.stdout + checked.stderr
    assert "Success" in checked.stdout


def test_mypy_sees_a_type_error(tmp_path):
    probe = tmp_path / "probe.py"
    probe.write_text("def f(x: int) -> str:\n    return x\n")
    checked = _run("mypy", "--cache-dir", str(tmp_path / "cache"), str(probe), cwd=tmp_path)
    assert checked.returncode == 1 and "incompatible return value" in checked.stdout.lower()
