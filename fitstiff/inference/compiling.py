"""Compiling functions of a problem once per structure (:meth:`Problem.compiled
<fitstiff.inference.problem.Problem.compiled>`, :func:`compiled_batch`).

A function of a problem is compiled with ``jax.jit``, the problem's data arrays passed as
arguments (never baked in as constants), and the executable shared by every problem of one
structure (:meth:`~fitstiff.inference.problem.Problem.structure_key`); a batch of problems of
one structure runs as one ``vmap``-ed call.
"""

from __future__ import annotations

import collections
import functools
import inspect
import threading
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING

import equinox as eqx
import numpy as np

from fitstiff._jax import jax, jnp

if TYPE_CHECKING:
    from fitstiff.inference.problem import Problem

__all__ = ["compile_for", "compiled_batch", "fingerprint", "structure_key"]

#: functions compiled for one structure, shared by the problems of that structure
#: (:meth:`Problem.compiled`); the oldest is dropped beyond :data:`_SHARED_MAX`
_SHARED: collections.OrderedDict[tuple, Callable] = collections.OrderedDict()
_SHARED_MAX = 64
#: the problem whose call is running a shared compiled function (per thread): a trace reads
#: its static structure off it
_CALLER = threading.local()


_SHARED_LOCK = threading.Lock()     # the diagnosis compiles from two threads


def _share(key: tuple, jitted: Callable) -> None:
    """Keep ``jitted`` for ``key``, the oldest dropped beyond :data:`_SHARED_MAX` (a function
    still held by a problem stays usable; only new problems compile it again)."""
    with _SHARED_LOCK:
        _SHARED[key] = jitted
        _SHARED.move_to_end(key)
        while len(_SHARED) > _SHARED_MAX:
            _SHARED.popitem(last=False)


def _shareable(fn) -> bool:
    """Whether compilations of ``fn`` may be shared between problems: a module-level function
    (a bound method or a closure is one object per problem or per call)."""
    return inspect.isfunction(fn) and "<locals>" not in fn.__qualname__


def fingerprint(tree) -> tuple | None:
    """A hashable image of a pytree's structure and leaf values (arrays by their bytes), or
    ``None`` when a leaf cannot be hashed."""
    leaves, treedef = jax.tree.flatten(tree)
    out = []
    for leaf in leaves:
        if isinstance(leaf, (np.ndarray, jax.Array)):
            a = np.asarray(leaf)
            out.append((a.shape, a.dtype.str, a.tobytes()))
            continue
        try:
            hash(leaf)
        except TypeError:
            return None
        out.append((type(leaf), leaf))
    return (treedef, tuple(out))


def compile_for(problem: Problem, fn: Callable, options: Mapping[str, object]) -> Callable:
    """:meth:`Problem.compiled` without its per-problem cache: ``fn`` compiled for
    ``problem``, the executable shared by the problems of its structure."""
    key = (fn, tuple(sorted(options.items())))
    bound = functools.partial(fn, **options) if options else fn
    # the problem's arrays are split from its static structure once, not per call:
    # ``jax.jit`` over the array leaves and the arguments' arrays dispatches in about
    # 13 us against 51 us for ``equinox.filter_jit`` re-partitioning the problem
    # (a posterior step calls one function of about 1 ms)
    data, structure = eqx.partition(problem.data_arrays(), eqx.is_array)
    # and flattened once: a flat list of arrays is flattened in C++ per call, the
    # problem's modules in Python (about 80 us of a 1 ms posterior call)
    leaves, tree = jax.tree.flatten(data)
    shared = _shareable(fn) and problem.structure_key(leaves, tree, structure)
    with _SHARED_LOCK:
        jitted = _SHARED.get((key, shared)) if shared else None
    if jitted is None:
        def run(leaves, arg_data, arg_static):
            problem = _CALLER.problem
            arrays = eqx.combine(jax.tree.unflatten(tree, leaves), structure)
            return bound(problem.with_data_arrays(arrays),
                         *eqx.combine(arg_data, arg_static))

        jitted = jax.jit(run, static_argnums=2)
        if shared:
            _share((key, shared), jitted)

    def call(*args):
        caller = getattr(_CALLER, "problem", None)
        _CALLER.problem = problem       # the problem a (re)trace reads its structure off
        try:
            if all(isinstance(a, (np.ndarray, jax.Array)) for a in args):
                return jitted(leaves, args, (None,) * len(args))
            arg_data, arg_static = eqx.partition(args, eqx.is_array)
            return jitted(leaves, arg_data, arg_static)
        finally:
            _CALLER.problem = caller

    return call


def compiled_batch(problems: Sequence[Problem], fn: Callable, /, *, lanes: int | None = None,
                   **options) -> Callable:
    """``fn(problem, *args, **options)`` for each of ``problems`` at once, as one ``vmap``-ed,
    compiled call ``f(*args)`` whose arguments and results carry a leading problem axis.

    The problems must share one :meth:`Problem.structure_key` (a fleet's cylinders of one
    structure; :mod:`fitstiff.fleet`): their data arrays are stacked and ``fn`` is traced
    once, with the first problem's structure. ``lanes`` (at least ``len(problems)``) fixes
    the batch the executable is compiled for: the call pads the stack with copies of the last
    problem and drops their results, so one executable serves every batch of up to ``lanes``
    problems and a problem's lane computes the same bits whichever problems share its call.
    The executable is shared like :meth:`Problem.compiled`'s.
    """
    problems = list(problems)
    if not problems:
        raise ValueError("compiled_batch needs at least one problem")
    lanes = lanes or len(problems)
    if lanes < len(problems):
        raise ValueError(f"lanes={lanes} is fewer than the {len(problems)} problems")
    first = problems[0]
    data, structure = eqx.partition(first.data_arrays(), eqx.is_array)
    leaves, tree = jax.tree.flatten(data)
    key = first.structure_key(leaves, tree, structure)
    stacks = [leaves]
    for p in problems[1:]:
        if p.structure_key() != key or key is None:
            raise ValueError("compiled_batch: the problems differ in structure "
                             "(Problem.structure_key); batch only problems of one structure")
        stacks.append(jax.tree.flatten(eqx.partition(p.data_arrays(), eqx.is_array)[0])[0])
    pad = lanes - len(problems)
    stacks += [stacks[-1]] * pad
    stacked = [jnp.stack(xs) for xs in zip(*stacks)]
    shared = ((("lanes", lanes), fn, tuple(sorted(options.items()))), key) \
        if _shareable(fn) and key is not None else None
    with _SHARED_LOCK:
        jitted = _SHARED.get(shared) if shared else None
    if jitted is None:
        bound = functools.partial(fn, **options) if options else fn

        def run(stacked, args):
            template = _CALLER.problem

            def one(leaves, *lane_args):
                arrays = eqx.combine(jax.tree.unflatten(tree, leaves), structure)
                return bound(template.with_data_arrays(arrays), *lane_args)

            return jax.vmap(one)(stacked, *args)

        jitted = jax.jit(run)
        if shared:
            _share(shared, jitted)

    def call(*args):
        args = tuple(jnp.concatenate([a, jnp.repeat(a[-1:], pad, axis=0)]) if pad else a
                     for a in (jnp.asarray(a) for a in args))
        caller = getattr(_CALLER, "problem", None)
        _CALLER.problem = first
        try:
            out = jitted(stacked, args)
        finally:
            _CALLER.problem = caller
        return jax.tree.map(lambda x: x[:len(problems)], out) if pad else out

    return call


def structure_key(problem: Problem, leaves=None, tree=None, structure=None) -> tuple | None:
    """What a function compiled for ``problem`` depends on besides its data arrays (hashable;
    ``None`` when some static part cannot be hashed): the arrays' tree and shapes (``leaves``
    and ``tree`` of its :meth:`~fitstiff.inference.problem.Problem.data_arrays` when the
    caller has them split, with their static ``structure``), the model's values (the start
    values and the fixed ones live in it), the free parameters and nuisances, the logs'
    lengths and whether each was denoised."""
    if leaves is None:
        data, structure = eqx.partition(problem.data_arrays(), eqx.is_array)
        leaves, tree = jax.tree.flatten(data)
    static = fingerprint(structure)
    model = fingerprint(problem.model)
    if static is None or model is None:
        return None
    return (tree, tuple((np.shape(a), np.dtype(a.dtype).str) for a in leaves), static,
            model, tuple(problem.par.names), tuple(problem.nuisance_names),
            tuple(sorted(problem.fixed_nuisances)), problem.has_friction,
            tuple(len(log) for log in problem.logs), tuple(problem.denoised))
