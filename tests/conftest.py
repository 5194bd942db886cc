"""Tests run in float64: the product of 46 RC stages needs it (entry points choose).

Compiled programs are shared between the test processes of one run, and only
that run: the controller makes an empty JAX compilation cache in a temporary
folder and removes it at the end; every worker (and every `hybrid` command a
test starts, through ``HYBRID_JAX_CACHE``) reads and writes it. Under
``pytest -n 2`` both workers compile the diagnose search and the fitters for
the same shapes; with the cache each program is compiled once per run. Nothing
is written into the user's ~/.cache, and every run starts cold, as CI does.
A test that needs a cold compile in its own process (the hang guard) turns the
cache off for its subprocess.
"""

import os
import shutil
import tempfile

import jax

CACHE_ENV = "HYBRID_JAX_CACHE"

jax.config.update("jax_enable_x64", True)


def pytest_configure(config):
    if not hasattr(config, "workerinput"):  # the controller, or a run without xdist
        where = tempfile.mkdtemp(prefix="hybrid-test-jax-cache-")
        config._hybrid_jax_cache = where
        os.environ[CACHE_ENV] = where  # workers start after this and inherit it
    jax.config.update("jax_compilation_cache_dir", os.environ[CACHE_ENV])
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)


def pytest_unconfigure(config):
    where = getattr(config, "_hybrid_jax_cache", None)
    if where:
        shutil.rmtree(where, ignore_errors=True)
