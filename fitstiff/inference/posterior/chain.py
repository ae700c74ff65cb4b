"""The posterior's chain file: an emcee backend storing the chain in HDF5, plus what a resumed
run must match.

With ``backend`` (a path) :func:`fitstiff.inference.posterior.sample_posterior` hands emcee's
sampler a :class:`ChainBackend`: an :class:`emcee.backends.Backend`, the interface the sampler
writes and reads through (``reset``, ``grow``, ``save_step``; ``iteration``, ``shape``,
``accepted``, ``random_state``, ``get_chain``, ``get_log_prob``, ``get_last_sample``), with storage
of fitstiff's own. The steps are written in batches at most a second apart (opening the file for
every step costs more than a step of a small problem), and at once when the run is interrupted.
:class:`ChainStore` adds a :func:`signature` of the problem (model, names, data hash, noise
model, priors, walkers), the estimated noise settings and the least-squares optimum.
``resume=True`` checks the signature and continues from the last stored step with the stored
random state, so an interrupted and resumed run gives the same chain as an uninterrupted one.

**The file** (``chain.h5``; read it with ``ChainBackend(path, read_only=True).get_chain()`` or
:meth:`ChainStore.read`):

==================================  ===========================================================
``chain/chain``                     ``(steps, walkers, sampled coordinates)`` walker positions
``chain/log_prob``                  ``(steps, walkers)`` their log-posterior
``chain/blobs``                     ``(steps, walkers, k + S)`` with the force offsets
                                    integrated out: what their conditional draws need of
                                    each position
                                    (:attr:`~fitstiff.inference.posterior.LogPosterior.blobs`)
``chain/accepted``                  ``(walkers,)`` accepted proposals per walker
``chain/steps``                     the number of stored steps (written last: a batch counts
                                    once it is whole)
``chain/rng_keys``, ``rng_rest``    the sampler's random state after the last stored step
                                    (MT19937 keys; position, has-gauss flag, cached gaussian)
``fitstiff`` attributes             ``signature``, ``noise``, ``theta_start``
``fitstiff/kept_theta``             the full ``theta`` of the kept draws
==================================  ===========================================================

Every value is written in place (no attribute is rewritten per batch), so the file does not
grow beyond its data. Chains written before issue 14 (emcee's :class:`HDFBackend` group
``mcmc``) are still read, through emcee's own backend.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import time
from collections.abc import Mapping
from pathlib import Path

import emcee
import h5py
import numpy as np

from fitstiff.errors import InputError
from fitstiff.inference.likelihood import NoiseModel, noise_from_dict
from fitstiff.inference.priors import Priors
from fitstiff.inference.problem import Problem
from fitstiff.io.output import ensure_room
from fitstiff.physics.params import Parameterization

__all__ = ["CHAIN", "KEPT", "ChainBackend", "ChainStore", "StoredChain", "fixed_values",
           "signature"]

CHAIN = "chain.h5"                  # the chain file, resumable
KEPT = "kept_theta"                 # chain.h5 fitstiff/kept_theta: full theta of the kept draws
_LEGACY = "mcmc"                    # emcee's HDFBackend group (chain files before issue 14)


def fixed_values(problem: Problem) -> dict[str, float]:
    """The values of the parameters the problem holds fixed (SI)."""
    values = Parameterization(problem.model).values(problem.model)
    return {n: v for n, v in values.items() if n in problem.par_fixed}


def signature(problem: Problem, noise: NoiseModel, priors: Priors,
               walkers: int) -> dict[str, object]:
    """What must match for a stored chain to be continued."""
    h = hashlib.sha256()
    for log, weights in zip(problem.logs, problem.sample_weights):
        for a in (log.displacement, log.force, log.time, log.pressure_a, log.pressure_b,
                  weights):
            h.update(b"-" if a is None else np.ascontiguousarray(a, dtype=float).tobytes())
    return {"model": problem.model.spec, "names": list(problem.names), "walkers": walkers,
            "noise_model": noise.to_dict(), "priors": priors.to_dict(),
            "fixed": fixed_values(problem), "data_sha256": h.hexdigest()}


class ChainBackend(emcee.backends.Backend):
    """An emcee backend keeping the chain in the ``chain`` group of an HDF5 file (the layout
    in the module docstring), steps buffered and written in batches at most
    :attr:`flush_seconds` apart. Every read writes the pending steps first;
    :func:`~fitstiff.inference.posterior.sample_posterior` flushes when interrupted, so a hard kill
    loses at most :attr:`flush_seconds` of sampling and never a stored step."""

    GROUP = "chain"
    flush_seconds = 1.0

    def __init__(self, path: str | os.PathLike, *, read_only: bool = False):
        # not emcee's Backend.__init__: its in-memory arrays are not used
        self.path = Path(path)
        self.read_only = read_only
        self.dtype = np.float64
        self._pending: list[tuple[np.ndarray, np.ndarray, np.ndarray, tuple,
                                  np.ndarray | None]] = []
        self._stored: int | None = None          # stored steps, once read
        self._shape: tuple[int, int] | None = None
        self._blobs: bool | None = None          # whether the chain has blobs, once read
        self._flushed_at = time.monotonic()

    @property
    def initialized(self) -> bool:
        """Whether the file holds a chain (emcee's sampler continues it, else resets)."""
        try:
            with h5py.File(self.path, "r") as f:
                return self.GROUP in f
        except OSError:
            return False

    def reset(self, nwalkers: int, ndim: int) -> None:
        """An empty chain of ``nwalkers`` walkers in ``ndim`` coordinates (the file's other
        content stays)."""
        self._writable()
        self._pending = []
        with h5py.File(self.path, "a") as f:
            if self.GROUP in f:
                del f[self.GROUP]
            g = f.create_group(self.GROUP)
            g.create_dataset("chain", (0, nwalkers, ndim), maxshape=(None, nwalkers, ndim),
                             dtype=self.dtype, chunks=True)
            g.create_dataset("log_prob", (0, nwalkers), maxshape=(None, nwalkers),
                             dtype=self.dtype, chunks=True)
            g.create_dataset("accepted", data=np.zeros(nwalkers))
            g.create_dataset("steps", data=0)
            g.create_dataset("rng_keys", (624,), dtype=np.uint32)
            g.create_dataset("rng_rest", (3,), dtype=np.float64)
        self._stored, self._shape, self._blobs = 0, (int(nwalkers), int(ndim)), False

    @property
    def shape(self) -> tuple[int, int]:
        """``(walkers, coordinates)``."""
        if self._shape is None:
            with h5py.File(self.path, "r") as f:
                self._shape = tuple(int(n) for n in f[self.GROUP]["chain"].shape[1:])
        return self._shape

    @property
    def iteration(self) -> int:
        """The number of steps, stored and pending."""
        if self._stored is None:
            with h5py.File(self.path, "r") as f:
                self._stored = int(f[self.GROUP]["steps"][()])
        return self._stored + len(self._pending)

    @property
    def accepted(self) -> np.ndarray:
        self.flush()
        with h5py.File(self.path, "r") as f:
            return f[self.GROUP]["accepted"][...]

    @property
    def random_state(self) -> tuple | None:
        """The sampler's random state after the last step (``None`` before the first)."""
        if self._pending:
            return self._pending[-1][3]
        if self.iteration == 0:
            return None
        with h5py.File(self.path, "r") as f:
            g = f[self.GROUP]
            pos, has_gauss, cached = g["rng_rest"][...]
            return ("MT19937", g["rng_keys"][...], int(pos), int(has_gauss), float(cached))

    def has_blobs(self) -> bool:
        """Whether the steps carry blobs (a ``(walkers, width)`` float array per step)."""
        if self._blobs is None:
            try:
                with h5py.File(self.path, "r") as f:
                    self._blobs = "blobs" in f[self.GROUP]
            except (OSError, KeyError):
                self._blobs = False
        return self._blobs

    def grow(self, ngrow: int, blobs) -> None:
        """Nothing to set aside (the datasets grow as the steps are written); with
        ``blobs`` on a new chain, their dataset is made (its width from them)."""
        if blobs is None:
            if self.has_blobs():
                raise ValueError(f"{self.path}: the chain has blobs and the new steps none")
            return
        blobs = np.asarray(blobs, dtype=float)
        if blobs.ndim != 2:
            raise ValueError(f"blobs of shape {blobs.shape}: fitstiff's chain file stores a "
                             "(walkers, width) float array per step")
        if self.has_blobs():
            return
        if self.iteration:
            raise ValueError(f"{self.path}: the chain's {self.iteration} steps have no blobs")
        self._writable()
        with h5py.File(self.path, "a") as f:
            f[self.GROUP].create_dataset("blobs", (0,) + blobs.shape,
                                         maxshape=(None,) + blobs.shape, dtype=self.dtype,
                                         chunks=True)
        self._blobs = True

    def save_step(self, state: emcee.State, accepted: np.ndarray) -> None:
        self._writable()
        self._pending.append((np.array(state.coords), np.array(state.log_prob),
                              np.array(accepted), state.random_state,
                              None if state.blobs is None else np.array(state.blobs)))
        if time.monotonic() - self._flushed_at >= self.flush_seconds:
            self.flush()

    def flush(self) -> None:
        """Write the pending steps."""
        if self._pending:
            coords, log_prob, accepted, states, blobs = zip(*self._pending)
            _, keys, pos, has_gauss, cached = states[-1][:5]
            series = [("chain", np.stack(coords)), ("log_prob", np.stack(log_prob))]
            if self.has_blobs():
                series.append(("blobs", np.stack(blobs)))
            with h5py.File(self.path, "a") as f:
                g = f[self.GROUP]
                # never start a write the disk cannot finish (the file keeps its last batch):
                # the steps, and a new chunk of every dataset they may open
                chunks = sum(np.prod(g[name].chunks) * g[name].dtype.itemsize
                             for name, _ in series)
                ensure_room(self.path.parent, sum(v.nbytes for _, v in series) + chunks,
                            what=f"the next {len(coords)} steps of the chain")
                start, k = int(g["steps"][()]), len(coords)
                for name, values in series:
                    g[name].resize(start + k, axis=0)
                    g[name][start:] = values
                g["accepted"][...] = g["accepted"][...] + np.sum(accepted, axis=0)
                g["rng_keys"][...] = keys
                g["rng_rest"][...] = (pos, has_gauss, cached)
                g["steps"][()] = start + k
            self._stored, self._pending = start + k, []
        self._flushed_at = time.monotonic()

    def get_value(self, name: str, flat: bool = False, thin: int = 1, discard: int = 0):
        """``chain``, ``log_prob`` or ``blobs`` (emcee's
        :meth:`~emcee.backends.Backend.get_chain`, :meth:`~emcee.backends.Backend.get_log_prob`,
        :meth:`~emcee.backends.Backend.get_blobs`; ``blobs``: None without)."""
        self.flush()
        if self.iteration <= 0:
            raise AttributeError("the chain has no step yet")
        if name == "blobs" and not self.has_blobs():
            return None
        with h5py.File(self.path, "r") as f:
            v = f[self.GROUP][name][discard + thin - 1:self.iteration:thin]
        if flat:
            return v.reshape((-1,) + v.shape[2:])
        return v

    def _writable(self) -> None:
        if self.read_only:
            raise RuntimeError(f"{self.path}: opened read-only")


@dataclasses.dataclass(frozen=True)
class StoredChain:
    """What a chain file holds (:meth:`ChainStore.read`).

    Attributes:
        chain: ``(steps, walkers, sampled coordinates)``.
        log_prob: ``(steps, walkers)``.
        theta_start: the full ``theta`` the run started from (``None`` in an older file).
        kept: ``(draws, walkers, size)``, the full ``theta`` of the kept draws, the integrated
            entries' conditional draws included (``None`` when not stored).
    """

    chain: np.ndarray
    log_prob: np.ndarray
    theta_start: np.ndarray | None
    kept: np.ndarray | None


class ChainStore:
    """The chain file: the chain (:class:`ChainBackend`) plus fitstiff's settings (signature
    of the problem, estimated noise settings, least-squares optimum, kept draws) for
    :func:`~fitstiff.inference.posterior.sample_posterior` ``resume`` and the report."""

    _GROUP = "fitstiff"

    def __init__(self, path: str | os.PathLike, *, read_only: bool = False):
        self.path = Path(path)
        self.backend = ChainBackend(self.path, read_only=read_only)

    def write_settings(self, signature: Mapping[str, object], *, settings: NoiseModel,
                       theta_start: np.ndarray) -> None:
        """Store what a resumed run needs: the signature, the estimated noise settings and
        the least-squares optimum they (and the turning-point columns) were taken at."""
        with h5py.File(self.path, "a") as f:
            group = f.require_group(self._GROUP)
            group.attrs["signature"] = json.dumps(signature, sort_keys=True)
            group.attrs["noise"] = json.dumps(settings.to_dict())
            group.attrs["theta_start"] = np.asarray(theta_start, dtype=float)

    def write_kept(self, thetas: np.ndarray) -> None:
        """Store the full ``theta`` of every kept draw ``(draws, walkers, size)``: the chain
        holds the sampled coordinates only, these add the integrated entries' conditional
        draws (read by the report)."""
        with h5py.File(self.path, "a") as f:
            group = f.require_group(self._GROUP)
            if KEPT in group:
                del group[KEPT]
            group.create_dataset(KEPT, data=np.asarray(thetas, dtype=float))

    def read(self) -> StoredChain:
        """The stored chain and what fitstiff keeps beside it (a file of fitstiff before
        issue 14 through emcee's :class:`~emcee.backends.HDFBackend`).

        Raises:
            OSError, KeyError, AttributeError: not a chain file, or one without a step.
        """
        backend: emcee.backends.Backend = self.backend
        with h5py.File(self.path, "r") as f:
            if ChainBackend.GROUP not in f and _LEGACY in f:
                backend = emcee.backends.HDFBackend(str(self.path), name=_LEGACY,
                                                    read_only=True)
            group = f.get(self._GROUP)
            start = np.asarray(group.attrs["theta_start"]) if group is not None else None
            kept = np.asarray(group[KEPT]) if group is not None and KEPT in group else None
        return StoredChain(chain=backend.get_chain(), log_prob=backend.get_log_prob(),
                           theta_start=start, kept=kept)

    def resume(self, signature: Mapping[str, object]) -> tuple[NoiseModel, np.ndarray]:
        """Check the stored chain against ``signature``; the stored noise settings and
        least-squares optimum."""
        where = str(self.path)
        try:
            with h5py.File(self.path, "r") as f:
                attrs = dict(f[self._GROUP].attrs)
                legacy = ChainBackend.GROUP not in f and _LEGACY in f
            iterations = 0 if legacy else self.backend.iteration
        except (OSError, KeyError):
            raise InputError(where, "--resume", "holds no chain to resume",
                             "run without --resume first") from None
        if legacy:
            raise InputError(where, "--resume", "holds a chain written by an older fitstiff "
                             "(emcee's HDF5 layout), which this version reads but does not "
                             "continue", "run without --resume to start over")
        if iterations == 0:
            raise InputError(where, "--resume", "holds no sampled step yet",
                             "run without --resume")
        stored = json.loads(attrs["signature"])
        mine = json.loads(json.dumps(signature, sort_keys=True))
        for key in sorted(mine):
            if stored.get(key) != mine[key]:
                raise InputError(where, "--resume", f"the chain was sampled with another {key} "
                                 f"({_short(stored.get(key))} vs {_short(mine[key])} now)",
                                 "resume with the original logs and options, or drop --resume "
                                 "to start over")
        if mine.get("integrated") and not self.backend.has_blobs():
            raise InputError(where, "--resume", "holds a chain written by an older fitstiff "
                             "without the statistics of the integrated force offsets (chain/"
                             "blobs), which this version needs to draw them",
                             "run without --resume to start over")
        return noise_from_dict(json.loads(attrs["noise"])), np.asarray(attrs["theta_start"])


def _short(value: object) -> str:
    text = json.dumps(value) if not isinstance(value, str) else value
    return text if len(text) <= 60 else text[:57] + "..."
