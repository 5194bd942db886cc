"""How an entry point sets up JAX's CPU backend, before any JAX work: devices and compiling.

`use_cpu_cores`: one JAX CPU device per core. `use_quick_compiles`: XLA:CPU's
loop emitters instead of its fusion emitters, at LLVM's optimisation level 1,
which compile the search's programs in about half the time.
`use_compilation_cache`: JAX's persistent compilation cache, which keeps
compiled programs between processes and across a release within one.

XLA's CPU backend runs one program on one core at a time, apart from the
multi-threaded kernels inside it (large matrix products). Work made of
independent parts — `diagnose`'s Levenberg–Marquardt lanes, `fit_batch`'s
fits — runs its parts side by side only when JAX has several CPU devices to
spread them over (`hybrid.discovery.fit_lanes`, `hybrid.fit_batch`). That
count is fixed when JAX starts its backend, so it is an entry point's choice,
like float64: the `hybrid` command and the benchmarks call this; the library
never does.
"""

from __future__ import annotations

import os

from ._errors import InputError

#: Where `use_compilation_cache` keeps compiled programs by default (the `hybrid` command's cache too).
DEFAULT_CACHE = os.path.join("~", ".cache", "hybrid", "jax")
#: The environment variable that names the cache's folder; ``off`` turns it off.
CACHE_ENV = "HYBRID_JAX_CACHE"

#: Most CPU devices `use_cpu_cores` gives by default. Every device holds its own copy of the
#: data a sharded program shares (a diagnose's recordings), and a search has 16–30 lanes to deal out:
#: beyond 8 devices memory grows with the core count while the lanes per device hardly fall.
MAX_DEFAULT_DEVICES = 8


def available_cores() -> int:
    """Cores this process may run on (its CPU affinity where the system says, else the CPU count)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def use_cpu_cores(n: int | None = None) -> int | None:
    """Give JAX `n` CPU devices (default: one per core, at most `MAX_DEFAULT_DEVICES`) unless the user chose.

    Call it at the start of a script, before JAX computes anything: JAX fixes
    its devices when its backend starts. A choice made outside the script
    wins: ``JAX_NUM_CPU_DEVICES`` in the environment (``JAX_NUM_CPU_DEVICES=1``
    runs everything on one device, as before), or XLA_FLAGS's
    ``--xla_force_host_platform_device_count``. Once the backend has started,
    nothing changes.

    **Returns:** the number of CPU devices set, or None where it left JAX's
    as they were (the user's choice, or a backend already started).
    """
    import jax

    if "JAX_NUM_CPU_DEVICES" in os.environ or "xla_force_host_platform_device_count" in os.environ.get(
        "XLA_FLAGS", ""
    ):
        return None
    count = int(n) if n is not None else min(available_cores(), MAX_DEFAULT_DEVICES)
    if count < 1:
        raise InputError(f"use_cpu_cores needs at least one device, got {n!r}")
    try:
        jax.config.update("jax_num_cpu_devices", count)
    except RuntimeError:  # the backend has started: its devices stay as they are
        return None
    return count


#: The XLA:CPU options `use_quick_compiles` sets, by name. XLA's fusion emitters (its default) take longer
#: to compile this project's programs than its older loop emitters and run them no faster: with jaxlib
#: 0.10.2 on the 2-core machine, `diagnose` on a 60 s, 30 Hz recording compiled in 0.61× the time and
#: ran in 0.92× (`python benchmarks/compile_emitters.py`). LLVM's optimisation level 1 instead of XLA's
#: 2 compiles in 0.86× the time again and runs as fast (0.77× on the second call, one run each): the
#: programs are loops of small matrix products (the lanes' LM steps, the scans over samples), which
#: the level-2 passes do not speed up. The same cause and gain (to 1e-9) under all three settings.
#: XLA stops at once on a flag it does not know, so they are set only for the jaxlib series they were
#: measured on (pyproject.toml pins it); re-measure when that pin moves.
QUICK_COMPILE_FLAGS = {
    "xla_cpu_use_fusion_emitters": "--xla_cpu_use_fusion_emitters=false",
    "xla_backend_optimization_level": "--xla_backend_optimization_level=1",
}
_QUICK_COMPILE_JAXLIB = "0.10."


def use_quick_compiles() -> bool:
    """Have XLA:CPU compile with its loop emitters at LLVM's level 1 (`QUICK_COMPILE_FLAGS`) unless the user chose.

    Call it at the start of a script, before JAX computes anything: XLA reads
    ``XLA_FLAGS`` when its backend starts, and ignores it after. A choice made
    outside the script wins, option by option: an option already named in
    ``XLA_FLAGS`` is left as it is. The programs compute the same functions
    either way; only the code XLA generates for them differs (results agree to
    rounding).

    **Returns:** True where it added a flag to ``XLA_FLAGS``; False where it
    left it as it was (the user's choices, or a jaxlib it was not measured on).
    """
    import jaxlib

    flags = os.environ.get("XLA_FLAGS", "")
    if not jaxlib.__version__.startswith(_QUICK_COMPILE_JAXLIB):
        return False
    added = [flag for name, flag in QUICK_COMPILE_FLAGS.items() if name not in flags]
    if not added:
        return False
    os.environ["XLA_FLAGS"] = " ".join([flags, *added]).strip()
    return True


def use_compilation_cache(folder: str | os.PathLike[str] | None = None) -> str | None:
    """Keep compiled programs in JAX's persistent compilation cache, in `folder`: an entry point's choice.

    `diagnose` compiles its search for each new length class in a process (most of
    a first call's time), and `fit` and `diagnose` release every compiled program of
    the process when they hold too many (`hybrid.util.ProgramBudget`): in a probe's
    script a fit of a fifth new length released the diagnose programs, and the next
    diagnose of a length already seen compiled them all again. With the cache, the
    programs are read back instead of compiled, in this process and the next
    (`benchmarks/diagnose.py` measures a command line's diagnose with the cache empty
    and warm). Every program is kept, however quick its compile
    (``jax_persistent_cache_min_compile_time_secs`` 0).

    **Arguments:**

    - `folder`: the cache's folder; default ``$HYBRID_JAX_CACHE``, else
      ``~/.cache/hybrid/jax`` (the `hybrid` command's). ``"off"`` (or an empty
      ``$HYBRID_JAX_CACHE``, ``0``, ``none``, ``false``) leaves JAX as it is.

    **Returns:** the folder in use, or None where the cache was left off.

    **Raises:** `InputError` where the folder cannot be made or written (a
    file of that name, a path under a file): JAX would otherwise warn at each
    program it fails to write, and compile every one afresh.
    """
    import jax

    where = os.fspath(folder) if folder is not None else os.environ.get(CACHE_ENV, DEFAULT_CACHE)
    if where.strip().lower() in ("", "0", "off", "none", "false"):
        return None
    where = os.path.expanduser(where)
    try:
        os.makedirs(where, exist_ok=True)
    except OSError as error:
        reason = error.strerror or type(error).__name__
        raise InputError(
            f"{where} cannot hold the compilation cache ({reason}): give a folder this process may write, or off"
        ) from None
    if not os.access(where, os.W_OK | os.X_OK):
        raise InputError(
            f"{where} cannot hold the compilation cache (not writable): give a folder this process may write, "
            "or off"
        )
    jax.config.update("jax_compilation_cache_dir", where)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    return where
