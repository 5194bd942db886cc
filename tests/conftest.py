"""Tests run in float64: the product of 46 RC stages needs it (entry points choose).

The CLI's persistent compilation cache is off here: tests that call
`hybrid.cli.main` must not write into the user's ~/.cache.
"""

import os

import jax

jax.config.update("jax_enable_x64", True)
os.environ["HYBRID_JAX_CACHE"] = "off"
