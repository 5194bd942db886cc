"""`hybrid.use_compilation_cache`: a script's way to keep compiled programs on disk, as the command does.

A probe's script that alternated diagnoses of one length with fits of new lengths waited 77–80 s for
the diagnose after every fifth new fit length (the fit's budget released every program) against 16–23 s
warm; with the persistent cache on, 21 s. The library only offered it through the command line.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

_SCRIPT = """
import json, sys
import jax
import hybrid
where = hybrid.use_compilation_cache(*sys.argv[1:])
jax.jit(lambda x: x * 2.0 + 1.0)(jax.numpy.arange(3.0)).block_until_ready()
print(json.dumps({"where": where, "dir": jax.config.jax_compilation_cache_dir}))
"""


def _run(tmp_path, *args, env_cache=None):
    env = {k: v for k, v in os.environ.items() if k != "HYBRID_JAX_CACHE"}
    env["HOME"] = str(tmp_path / "home")  # the default folder, under a home of the test's own
    if env_cache is not None:
        env["HYBRID_JAX_CACHE"] = env_cache
    run = subprocess.run([sys.executable, "-c", _SCRIPT, *args], capture_output=True, text=True, env=env)
    assert run.returncode == 0, run.stderr[-2000:]
    return json.loads(run.stdout.strip().splitlines()[-1])


def test_the_cache_keeps_a_scripts_programs_in_the_folder_given_the_environments_or_the_default(tmp_path):
    given = tmp_path / "given"
    said = _run(tmp_path, str(given))
    assert said == {"where": str(given), "dir": str(given)} and any(given.iterdir())  # a program written
    named = tmp_path / "named"
    assert _run(tmp_path, env_cache=str(named))["where"] == str(named) and any(named.iterdir())
    default = tmp_path / "home" / ".cache" / "hybrid" / "jax"
    assert _run(tmp_path)["where"] == str(default) and any(default.iterdir())


def test_off_leaves_jax_as_it_is(tmp_path):
    assert _run(tmp_path, "off") == {"where": None, "dir": None}
    assert _run(tmp_path, env_cache="off") == {"where": None, "dir": None}
    assert not (tmp_path / "home").exists()  # nothing written under the default folder either


def test_a_folder_that_cannot_hold_the_cache_is_refused_in_one_line(tmp_path):
    """A verifier's ``HYBRID_JAX_CACHE`` naming a file: the function returned the path as in use, and JAX
    then warned in two lines of Python at each program it could not write."""
    import pytest

    import hybrid
    from hybrid.util._errors import InputError

    afile = tmp_path / "afile"
    afile.write_text("not a folder")
    for bad in (afile, afile / "under"):
        with pytest.raises(InputError, match="cannot hold the compilation cache .*give a folder"):
            hybrid.use_compilation_cache(bad)
    env = {**os.environ, "HYBRID_JAX_CACHE": str(afile)}
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "hybrid.cli",
            "simulate",
            "--drive",
            "sine",
            "--duration",
            "2",
            "--out",
            "s.csv",
        ],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        env=env,
    )
    assert run.returncode == 0 and (tmp_path / "s.csv").is_file(), run.stderr[-2000:]
    said = [line for line in run.stderr.splitlines() if line.strip()]
    assert said == [
        f"hybrid: warning: HYBRID_JAX_CACHE: {afile} cannot hold the compilation cache (File exists): give a "
        "folder this process may write, or off; compiling without it"
    ], run.stderr
