"""The posterior's chain file: emcee's HDF5 backend plus what a resumed run must match.

With ``backend`` (a path) :func:`fitstiff.posterior.sample_posterior` writes the chain to an
:class:`emcee.backends.HDFBackend` file (:class:`ChainStore`; steps written in batches at most a
second apart, and at once when the run is interrupted), together with a :func:`signature` of
the problem (model, names, data hash, noise model, priors, walkers), the estimated noise
settings and the least-squares optimum. ``resume=True`` checks the signature and continues
from the last stored step with the stored random state, so an interrupted and resumed run
gives the same chain as an uninterrupted one.
"""

from __future__ import annotations

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
from fitstiff.likelihood import NoiseModel, noise_from_dict
from fitstiff.params import Parameterization
from fitstiff.priors import Priors
from fitstiff.problem import Problem

__all__ = ["CHAIN", "KEPT", "ChainStore", "fixed_values", "signature"]

CHAIN = "chain.h5"                  # the emcee chain (HDF5 backend), resumable
KEPT = "kept_theta"                 # chain.h5 fitstiff/kept_theta: full theta of the kept draws


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


class ChainStore:
    """The HDF5 chain file: emcee's ``mcmc`` group plus fitstiff's settings (signature of the
    problem, estimated noise settings) for :func:`sample_posterior` ``resume``."""

    _GROUP = "fitstiff"

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self.backend = _BufferedHDFBackend(str(self.path), name="mcmc")

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

    def compact(self) -> None:
        """Rewrite the file without the space the random-state attribute updates leave
        behind (about 5 kB per update), atomically."""
        self.backend.flush()
        tmp = self.path.with_name(f".{self.path.name}.compact")
        with h5py.File(self.path, "r") as src, h5py.File(tmp, "w") as dst:
            for name in src:
                src.copy(src[name], dst, name=name)
        os.replace(tmp, self.path)

    def resume(self, signature: Mapping[str, object]) -> tuple[NoiseModel, np.ndarray]:
        """Check the stored chain against ``signature``; the stored noise settings and
        least-squares optimum."""
        where = str(self.path)
        try:
            with h5py.File(self.path, "r") as f:
                attrs = dict(f[self._GROUP].attrs)
                iterations = int(f["mcmc"].attrs["iteration"])
        except (OSError, KeyError):
            raise InputError(where, "--resume", "holds no chain to resume",
                             "run without --resume first") from None
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
        return noise_from_dict(json.loads(attrs["noise"])), np.asarray(attrs["theta_start"])


def _short(value: object) -> str:
    text = json.dumps(value) if not isinstance(value, str) else value
    return text if len(text) <= 60 else text[:57] + "..."


class _BufferedHDFBackend(emcee.backends.HDFBackend):
    """emcee's HDF5 backend writing the steps in batches, at most ``flush_seconds`` apart
    (opening the file for every step costs more than a step of a small problem). Every read
    writes the pending steps first; :func:`sample_posterior` flushes when interrupted, so a
    hard kill loses at most ``flush_seconds`` of sampling and never corrupts stored steps."""

    flush_seconds = 1.0

    def __init__(self, filename: str, *, name: str):
        super().__init__(filename, name=name)
        self._pending: list[tuple[np.ndarray, np.ndarray, np.ndarray, object]] = []
        self._flushed_at = time.monotonic()

    def save_step(self, state, accepted):
        self._pending.append((np.array(state.coords), np.array(state.log_prob),
                              np.array(accepted), state.random_state))
        if time.monotonic() - self._flushed_at >= self.flush_seconds:
            self.flush()

    def flush(self) -> None:
        """Write the pending steps."""
        if self._pending:
            coords, log_prob, accepted, _ = zip(*self._pending)
            with super().open("a") as f:
                g = f[self.name]
                start, k = int(g.attrs["iteration"]), len(coords)
                g["chain"][start:start + k] = np.stack(coords)
                g["log_prob"][start:start + k] = np.stack(log_prob)
                g["accepted"][:] += np.sum(accepted, axis=0)
                for i, v in enumerate(self._pending[-1][3]):
                    g.attrs[f"random_state_{i}"] = v
                g.attrs["iteration"] = start + k
            self._pending = []
        self._flushed_at = time.monotonic()

    def open(self, mode="r"):
        self.flush()
        return super().open(mode)
