"""Running a fleet: chunks of units on Dask workers, results kept per chunk, the population.

:func:`fit_fleet` discovers the units (:mod:`fitstiff.fleet.source`), skips those whose
inputs and settings are unchanged since a finished earlier run (their rows are read back from
the cache directory, keyed by each unit's input hash), sends the rest in chunks to the
workers (:func:`fitstiff.fleet.work.fit_units`), writes each chunk's rows to the cache as it
arrives (atomically: a chunk is there whole or not at all), and adds the population's flags
(:mod:`fitstiff.fleet.population`).

Where the work runs:

- ``workers=None`` (default): a ``distributed.LocalCluster`` of one process per core, one
  thread each, XLA's and the BLAS thread pools at one thread (no oversubscription), started
  and closed here;
- ``workers=1``: in this process, without Dask (for debugging, and for a laptop's small fleet);
- ``scheduler="tcp://HOST:PORT"``: an existing Dask cluster, unchanged (its workers need
  fitstiff installed; they read the logs by the paths given, so share the files).

Dask retries a chunk whose worker died (``distributed.scheduler.allowed-failures``), and a
chunk's rows come back whole: the table never loses or repeats a unit. A unit's row does not
depend on the chunk it ran in, the number of workers or their order (:mod:`~fitstiff.fleet.work`).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import pandas as pd

from fitstiff.errors import InputError
from fitstiff.fleet.population import DEFAULT_Q, population
from fitstiff.fleet.source import Unit, discover, input_hash
from fitstiff.fleet.work import BASE_COLUMNS, Settings, fit_units
from fitstiff.io.output import write_atomic
from fitstiff.physics.model import DEFAULT_MODEL

__all__ = ["fit_fleet", "WORKER_ENV", "CACHE_DIR", "FIT_OPTIONS", "default_workers", "worker_env"]

#: the per-chunk rows of finished units, inside the output directory (kept between runs)
CACHE_DIR = ".fleet-cache"
#: the environment of a local worker process: one thread for XLA and the BLAS libraries; on
#: a GPU, memory taken as needed (workers share the one device: none may take most of it)
WORKER_ENV = {"XLA_FLAGS": "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1",
              "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
              "XLA_PYTHON_CLIENT_PREALLOCATE": "false"}
#: the options of :func:`fitstiff.fit` a fleet passes on to each unit's fit
FIT_OPTIONS = ("solver", "max_steps", "starts", "seed", "denoise", "sample_range", "weights",
               "skip", "free")
#: units per task: enough to amortise a task's overhead, few enough to spread the work
_CHUNK = 8


def worker_env(lanes: int) -> dict[str, str]:
    """The environment of a local worker process (:data:`WORKER_ENV`). With batches
    (``lanes > 1``) and no ``JAX_PLATFORMS`` of the user's, JAX chooses the platform: a worker
    that sees a GPU sends its batches there (:func:`fitstiff._jax.on_host`); one unit at a
    time runs on the CPU."""
    from fitstiff._jax import PLATFORMS_GIVEN

    env = dict(WORKER_ENV)
    if lanes > 1 and not PLATFORMS_GIVEN:
        env["JAX_PLATFORMS"] = ""
    return env


def default_workers() -> int:
    """One worker per core this process may use."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except AttributeError:          # not Linux
        return max(os.cpu_count() or 1, 1)


def _chunks(units: Sequence[Unit], size: int) -> list[list[Unit]]:
    return [list(units[i:i + size]) for i in range(0, len(units), size)]


def _cached(cache: Path | None) -> dict[str, dict]:
    """Rows of finished units by input hash, from the cache's chunk files."""
    rows: dict[str, dict] = {}
    if cache is None or not cache.is_dir():
        return rows
    for part in sorted(cache.glob("chunk-*.parquet")):
        try:
            frame = pd.read_parquet(part)
        except Exception:      # noqa: BLE001  - a damaged cache file is refitted, not trusted
            continue
        for row in frame.to_dict("records"):
            rows[row["input_hash"]] = row
    return rows


def _store(cache: Path | None, rows: list[dict]) -> Path | None:
    """``rows`` written atomically as one chunk file of ``cache``, named by their input
    hashes; its path."""
    if cache is None or not rows:
        return None
    import hashlib

    name = hashlib.sha256("".join(sorted(r["input_hash"] for r in rows)).encode()).hexdigest()
    frame = pd.DataFrame(rows)
    path = cache / f"chunk-{name[:32]}.parquet"
    tmp = cache / f".{path.name}.{os.getpid()}.tmp"
    frame.to_parquet(tmp, index=False)
    write_atomic(path, tmp.read_bytes())
    tmp.unlink()
    return path


def _run_local(chunks, settings, done) -> None:
    for chunk in chunks:
        done(fit_units(chunk, settings))


def _run_dask(chunks, settings, done, *, keys: list[str], workers: int | None,
              scheduler: str | None) -> None:
    try:
        from distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise InputError(None, "--workers/--scheduler", "needs Dask distributed, which is not "
                         "installed", "pip install 'dask[distributed]', or give --workers 1")
    cluster = None
    if scheduler:
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError) as exc:
            raise InputError(None, f"--scheduler {scheduler}", f"cannot be reached ({exc})",
                             "start it (dask scheduler) or give its address as "
                             "tcp://HOST:PORT") from None
    else:
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=logging.ERROR,
                               env=worker_env(settings.lanes))
        client = Client(cluster)
    try:
        futures = client.map(fit_units, chunks, settings=settings, key=keys, pure=False)
        for future in as_completed(futures):
            done(future.result())
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def fit_fleet(source: str | os.PathLike | Sequence[Unit], *, model: str = DEFAULT_MODEL,
              fix: Mapping[str, float | None] | None = None,
              reading: Mapping[str, object] | None = None,
              workers: int | None = None, scheduler: str | None = None,
              lanes: int = 1, chunk: int = _CHUNK, diagnose: bool = False,
              q: float = DEFAULT_Q, cache: str | os.PathLike | None = None,
              progress: Callable[[int, int], None] | None = None,
              **fit_options) -> pd.DataFrame:
    """Fit every cylinder and run of a fleet and estimate its population.

    Args:
        source: a folder ``<cylinder>/[<run>/]*.csv``, a manifest CSV (columns
            ``cylinder``, ``run``, ``file``), or units from :func:`~fitstiff.fleet.discover`.
        model, fix: as for :func:`fitstiff.fit`; ``fit_options`` too (solver, max_steps,
            denoise, sample_range, weights, skip, free).
        reading: options of :func:`fitstiff.io.loading.load_logs` (columns, fmt,
            rig_overrides, ...).
        workers: local worker processes (default: one per core; 1: in this process).
        scheduler: the address of an existing Dask scheduler (then ``workers`` is unused).
        lanes: units per ``vmap``-ed solve (1 on CPUs; hundreds on a GPU).
        chunk: units per task.
        diagnose: also diagnose each unit (``accepted_effects``, held-out RMS columns).
        q: the false-discovery rate of the outlier and drift flags.
        cache: a directory for the finished units' rows: a later call with the same cache
            refits only units whose logs, sidecars or settings changed.
        progress: called with ``(units done, units)`` as chunks finish.

    Returns:
        One row per unit, sorted by cylinder and run (columns: see
        :data:`~fitstiff.fleet.work.BASE_COLUMNS`, the derived quantities and parameters
        with ``_stderr``, ``accepted_effects`` with ``diagnose``, then the flags of
        :class:`~fitstiff.fleet.population.Population`); ``attrs["population"]`` holds
        the population (``population.json``).
    """
    unknown = sorted(set(fit_options) - set(FIT_OPTIONS))
    if unknown:
        raise TypeError(f"fit_fleet() got unexpected keyword arguments {unknown}; the fit "
                        f"options are {', '.join(FIT_OPTIONS)}")
    units = _units(source)
    _check_counts(lanes=lanes, chunk=chunk, workers=workers)
    settings = Settings(model=model, fix=dict(fix or {}), fit=dict(fit_options),
                        reading=dict(reading or {}), lanes=lanes, diagnose=diagnose)
    text = settings.text()
    cache_dir = Path(cache) if cache is not None else None
    if cache_dir is not None:
        cache_dir.mkdir(parents=True, exist_ok=True)
    known = _cached(cache_dir)
    hashes = [input_hash(u, text) for u in units]
    todo = [u for u, h in zip(units, hashes) if h not in known]
    # by unit (a file that changes while the fleet runs is the worker's to hash)
    rows = {(u.cylinder, u.run): known[h] for u, h in zip(units, hashes) if h in known}
    total, finished = len(units), len(rows)

    def done(chunk_rows: list[dict]) -> None:
        nonlocal finished
        _store(cache_dir, chunk_rows)
        for row in chunk_rows:
            rows[(row["cylinder"], row["run"])] = row
        finished += len(chunk_rows)
        if progress is not None:
            progress(finished, total)

    if progress is not None:
        progress(finished, total)
    _run(_chunks(todo, chunk), settings, done, hashes=dict(zip(units, hashes)), workers=workers,
         scheduler=scheduler)
    table = [rows[(u.cylinder, u.run)] for u in units]
    _prune(cache_dir, table)
    return _with_population(pd.DataFrame(table), q)


def _prune(cache: Path | None, rows: list[dict]) -> None:
    """After a finished run: the cache holds this run's rows only, in one chunk file. The rows
    of units whose inputs changed or that left the fleet go (they would never be read
    again, and every later run would read them), and the chunk files of the batches merge
    into one. The merged file is written first and the others removed after, so an
    interrupted pruning leaves every row it had."""
    if cache is None or not rows:
        return
    parts = sorted(cache.glob("chunk-*.parquet"))
    if len(parts) == 1 and set(pd.read_parquet(parts[0], columns=["input_hash"])
                                ["input_hash"]) == {r["input_hash"] for r in rows}:
        return
    kept = _store(cache, rows)
    for part in parts:
        if part != kept:
            part.unlink(missing_ok=True)


def _units(source: str | os.PathLike | Sequence[Unit]) -> list[Unit]:
    """The units of ``source`` (discovered in a folder or manifest); an InputError if none."""
    units = list(source) if not isinstance(source, (str, os.PathLike)) else discover(source)
    if not units:
        raise InputError(str(source), "fleet", "holds no units", "give at least one cylinder")
    return units


def _check_counts(*, lanes: int, chunk: int, workers: int | None) -> None:
    """An InputError for a count below 1."""
    for flag, value in (("--lanes", lanes), ("--chunk", chunk)):
        if value < 1:
            raise InputError(None, f"{flag} {value}", "must be at least 1", "give 1 or more")
    if workers is not None and workers < 1:
        raise InputError(None, f"--workers {workers}", "must be at least 1", "give 1 or more")


def _run(chunks: list[list[Unit]], settings: Settings, done: Callable[[list[dict]], None], *,
         hashes: Mapping[Unit, str], workers: int | None, scheduler: str | None) -> None:
    """The chunks fitted here (one worker, no scheduler) or on Dask; ``done`` with each
    chunk's rows as it finishes."""
    if not chunks:
        return
    if scheduler is None and (workers or default_workers()) == 1:
        _run_local(chunks, settings, done)
    else:
        # a task's key names its units (Dask keeps one result per key)
        keys = [f"fitstiff-fleet-{hashes[c[0]][:20]}-{len(c)}" for c in chunks]
        _run_dask(chunks, settings, done, keys=keys, workers=workers or default_workers(),
                  scheduler=scheduler)


def _with_population(table: pd.DataFrame, q: float) -> pd.DataFrame:
    """The fleet's rows sorted by cylinder and run, the base columns first, with the
    population's flags and ``attrs["population"]``."""
    table = table.sort_values(["cylinder", "run_index"], kind="stable").reset_index(drop=True)
    first = [c for c in BASE_COLUMNS if c in table]
    table = table[first + [c for c in table.columns if c not in first]]
    fitted = population(table, q=q)
    table = pd.concat([table, fitted.flags.drop(columns=["cylinder", "run"])], axis=1)
    table.attrs["population"] = fitted.to_dict()
    return table

