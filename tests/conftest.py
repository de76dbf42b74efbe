"""Test configuration: the suite runs in float64 on the CPU (documented place that enables x64)."""

import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
