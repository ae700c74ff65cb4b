"""Import JAX with 64-bit floats enabled (stiff seal models need them).

Every fitstiff module that uses JAX imports ``jax`` / ``jnp`` from here so the flag is set
before the first array is made.
"""

import contextlib
import gc
import os

#: whether the user chose JAX's platforms (``JAX_PLATFORMS``); else fitstiff runs on the CPU
PLATFORMS_GIVEN = "JAX_PLATFORMS" in os.environ
os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402

from fitstiff import malloc  # noqa: E402

__all__ = ["PLATFORMS_GIVEN", "computed_apart", "jax", "jnp", "on_host", "release_compiled"]


def on_host() -> contextlib.AbstractContextManager:
    """A context in which JAX computes on the host's CPU, where the default device is an
    accelerator (else nothing changes).

    fitstiff runs on the CPU unless ``JAX_PLATFORMS`` says otherwise (set above): one fit's
    sequential scans are faster there (on one H100 with 16 cores, 3.8 warm fits a second on
    the GPU against 24 on the CPU; ``benchmarks/fleet_gpu.py``). Where a process does see a
    GPU (``JAX_PLATFORMS=cuda,cpu``), only the ``vmap``-ed batches of a fleet go to it; the
    reading, the problems' set-up and each fit's bookkeeping stay here, where each small
    operation does not wait for a device round trip.
    """
    if jax.default_backend() == "cpu":
        return contextlib.nullcontext()
    return jax.default_device(jax.devices("cpu")[0])


def release_compiled() -> None:
    """Free what JAX keeps of every function compiled so far in this process (executables,
    traces, lowered modules) and return the freed heap to the operating system.

    A long pipeline compiles functions it needs in one phase only (a fit's Jacobians, the
    turning-point columns, the sampler's log-posterior); kept, they add up: the default
    four-log posterior peaked at 985 MB resident, releasing them between its phases at
    563-585 MB (``benchmarks/posterior_default.py``, warm compilation cache). A function
    called again is traced again, and its executable read from the persistent compilation
    cache when one is set (the command line's) instead of compiled.
    """
    jax.clear_caches()
    gc.collect()
    malloc.trim()


def computed_apart(x):
    """``x``, computed apart from what uses it: its consumers read it from memory instead of
    having its computation fused into theirs.

    ``jax.lax.optimization_barrier`` does not do this on the CPU backend: XLA removes the
    barrier before it fuses. A conditional whose predicate is known only at run time stays a
    boundary, so ``x`` goes through one whose branches both return it. For the posterior's
    force residuals (32 walkers of a 4 000-sample log): the AR(1) whitening fused into the
    model cost 2.0 ms a call, apart 0.6 ms. The conditional itself is one thunk: a few
    microseconds.
    """
    return jax.lax.cond(jnp.isnan(x.ravel()[0]), lambda v: v + 0.0, lambda v: v, x)
