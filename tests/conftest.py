"""Tests run in float64: the product of 46 RC stages needs it (entry points choose)."""

import jax

jax.config.update("jax_enable_x64", True)
