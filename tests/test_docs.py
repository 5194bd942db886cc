"""The documentation builds, strictly: a broken link or cross-reference fails.

`mkdocs build --strict` (mkdocs.yml at the root, pages in docs/) renders the
API pages from the docstrings with mkdocstrings-python. A docstring reference
like [`FitResult`][] that no page documents, a link to a page or anchor that
does not exist, or a `::: hybrid.name` that is no longer there is a warning,
and --strict turns every warning into a failed build.
"""

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Seconds before the build counts as hung (it takes a few seconds here).
BUILD_TIMEOUT = 300


@pytest.mark.skipif(
    importlib.util.find_spec("mkdocs") is None or importlib.util.find_spec("mkdocstrings_handlers") is None,
    reason="mkdocs / mkdocstrings-python not installed: pip install -e '.[docs]' (make test installs it)",
)
def test_docs_build_strict(tmp_path):
    site = tmp_path / "site"
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "mkdocs",
            "build",
            "--strict",
            "--config-file",
            str(ROOT / "mkdocs.yml"),
            "--site-dir",
            str(site),
        ],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=BUILD_TIMEOUT,
    )
    log = done.stdout + done.stderr
    warnings = [line for line in log.splitlines() if "WARNING" in line or "ERROR" in line]
    assert done.returncode == 0, "mkdocs build --strict failed:\n" + ("\n".join(warnings) or log[-4000:])

    fitting = site / "api" / "fitting" / "index.html"
    assert fitting.is_file(), "the API page of hybrid.fit was not built"
    html = fitting.read_text(encoding="utf-8")
    assert 'id="hybrid.fit"' in html, "hybrid.fit has no entry on its API page"
    assert 'id="hybrid.FitResult"' in html
    assert (site / "api" / "sensitivity" / "index.html").is_file()
    for page in (
        "virtual-ipmc",
        "diagnose",
        "modelling",
        "command-line",
        "sensitivity",
        "benchmarks",
        "tests",
        "rig",
        "architecture",
        "table2",
    ):
        assert (site / page / "index.html").is_file(), f"docs/{page}.md was not built"
