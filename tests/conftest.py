"""Test configuration: the suite runs in float64 on the CPU (documented place that enables x64),
with its own temporary on-disk cache so that it neither reads nor fills the user's cache."""

import os
import tempfile

os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ["PAINTJAX_CACHE"] = tempfile.mkdtemp(prefix="paintjax-test-cache-")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
