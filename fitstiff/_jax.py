"""Import JAX with 64-bit floats enabled (stiff seal models need them).

Every fitstiff module that uses JAX imports ``jax`` / ``jnp`` from here so the flag is set
before the first array is made.
"""

import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402

__all__ = ["jax", "jnp"]
