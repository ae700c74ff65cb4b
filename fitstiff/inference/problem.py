"""The identification problem: model + logs -> one flat parameter vector -> whitened residuals.

Shared by least squares (:mod:`fitstiff.inference.fitting`) and the posterior
(:mod:`fitstiff.inference.posterior`), so both see the same coordinates and the same data.

The flat vector ``theta`` is ``[shared model parameters (unconstrained), per-log nuisances]``.
The per-log nuisances (:mod:`fitstiff.inference.nuisances`) are the force-channel offset and,
for models with a friction base, the initial friction state (a log may start mid-hysteresis);
either can be fixed with ``fix``. On request (``free``) the closing pressure of each log's
closed chambers is one too, for logs whose ``supply_bar`` is unknown or doubtful.

Residuals are whitened per channel: force residuals divided by the log's force-noise estimate,
and, for closed chambers whose pressure is logged, pressure residuals divided by the
pressure-noise estimate (these identify the polytropic exponent ``n``). Logs with the same
static structure are padded to one length and evaluated with one ``vmap``-ed scan, so the
compile time does not grow with the number of logs; padded samples carry zero weight.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
from collections.abc import Callable, Iterable, Mapping, Sequence

import equinox as eqx
import numpy as np

from fitstiff._jax import jax, jnp
from fitstiff.errors import InputError
from fitstiff.inference.nuisances import NUISANCE_PARAMS, NUISANCES, OPTIONAL_NUISANCES
from fitstiff.inference.selection import Selection
from fitstiff.inference.compiling import compile_for, compiled_batch, structure_key
from fitstiff.inference.stacking import (Group, ResidualSeries, build_groups, residual_series,
                                        same_structure)
from fitstiff.io.guards import check_logs
from fitstiff.io.log import Log
from fitstiff.physics.drive import Drive, drive_from_log
from fitstiff.physics.model import (Model, build_model, model_needs)
from fitstiff.physics.params import (CONSTANT_JACOBIAN, Param, Parameterization, find_param,
                                     named_params)
from fitstiff.physics.terms import FrictionBase
from fitstiff.segments.denoise import (chatters, denoise_displacement, reversal_samples,
                                       segment_velocity, smooth_acceleration, smooth_force,
                                       turning_points)
from fitstiff.segments.segmentation import Segmentation, segment
from fitstiff.signal.noise import estimate_noise, marginal_scale, noise_floor

__all__ = ["Problem", "compiled_batch", "ResidualSeries", "channel_noise", "CHANNELS",
           "CHUNKED_ROWS", "with_nuisances"]

#: the observed channels of a log, in the order of the residual vector
CHANNELS = ("force", "pressure_a", "pressure_b")
#: a problem whose residual vector would exceed this many entries (samples times logged
#: channels, all logs) is fitted in windows of its logs (:mod:`fitstiff.inference.chunks`),
#: its per-sample arrays kept on the host: from about 2.8 M samples with two logged pressures
CHUNKED_ROWS = 2**23
_DEFAULT_CLOSING_PA = 5e5      # gauge start value when neither rig nor log says more
_PRESSURE_NOISE_FLOOR = 10.0   # Pa, below any real sensor
_FORCE_NOISE_FLOOR = 1e-3      # N


def channel_noise(values: np.ndarray) -> float:
    """Gaussian-equivalent white-noise level of a sampled channel (MAD of 2nd differences)."""
    return estimate_noise(values)


class Problem:
    """Model, logs and the map from ``theta`` to whitened residuals.

    Args:
        logs: the logs to fit jointly (seal and chamber parameters shared).
        model: spec string or a built model (its values are the starting point).
        fix: parameters to hold: names (held at the model's value) or a mapping name ->
            SI value (``{"n": 1.4}``; ``None`` holds the model's value). Nuisance names
            ``offset`` / ``friction_state0`` fix those for every log (at 0).
        selection: the data options (:class:`~fitstiff.inference.selection.Selection`:
            denoising, the sample range, region weights, skipped and excluded samples, optional
            nuisances); or give its fields as keywords (``denoise=False``, ``skip=100``).
        segmentations: one :class:`~fitstiff.segments.segmentation.Segmentation` per log (reversals,
            pauses, regions, displacement noise), e.g. from
            :func:`~fitstiff.segments.segmentation.segment` with other options; default
            ``segment(log)`` for each log.
        chunked: keep the per-sample arrays as NumPy arrays on the host (views of the logs'
            where they can be) and fit in windows of the logs
            (:mod:`fitstiff.inference.chunks`: memory bounded in the log's length); default
            (``None``): when the residual vector would exceed :data:`CHUNKED_ROWS` entries.

    A problem is immutable: every attribute is set by the constructor. Compiled functions of
    it are made by :meth:`compiled`.
    """

    def __init__(self, logs: Sequence[Log], model: Model | str, *,
                 fix: Mapping[str, float | None] | Iterable[str] = (),
                 selection: Selection | None = None,
                 segmentations: Sequence[Segmentation] | None = None,
                 chunked: bool | None = None, **options):
        if not logs:
            raise InputError(None, "logs", "none given", "name at least one CSV log")
        self.selection = selection = Selection.given(selection, options)
        free = set(selection.free)
        if free - set(OPTIONAL_NUISANCES):
            raise InputError(None, f"--free {', '.join(sorted(free - set(OPTIONAL_NUISANCES)))}",
                             "is not an optional nuisance",
                             f"use one of: {', '.join(OPTIONAL_NUISANCES)}")
        self.logs = list(logs)
        check_logs(self.logs)
        self.chunked = host = bool(_rows(self.logs) > CHUNKED_ROWS if chunked is None
                                   else chunked)
        self.segmentations: list[Segmentation] = _segmentations(self.logs, segmentations)
        spec = model if isinstance(model, str) else model.spec
        needs = model_needs(model)
        self.displacement_noise = [s.noise for s in self.segmentations]
        self.denoised = [self._want_denoise(selection.denoise, s, log.displacement)
                         for log, s in zip(self.logs, self.segmentations)]
        self.drives: list[Drive] = []
        for log, seg, den in zip(self.logs, self.segmentations, self.denoised):
            drive = drive_from_log(log, needs_chamber=needs.chamber_geometry, still=seg.still,
                                   what=f"model '{spec}'",
                                   needs_supply="closing_pressure" not in free, host=host)
            array = np.asarray if host else jnp.asarray
            if den:
                x = denoise_displacement(log.displacement, seg.reversals, noise=seg.noise,
                                         still=seg.still)
                drive = (dataclasses.replace(drive, displacement=x) if host
                         else drive.with_displacement(x))
                if log.time is not None:
                    v = segment_velocity(x, log.time, seg.reversals, noise=seg.noise)
                    a = (smooth_acceleration(log.displacement, log.time, noise=seg.noise)
                         if needs.acceleration else None)
                    drive = dataclasses.replace(drive, velocity=array(v),
                                                acceleration=None if a is None else array(a))
            self.drives.append(drive)
        self.drives = same_structure(self.drives)
        if host:
            self.drives = [jax.tree.map(np.asarray, d) for d in self.drives]
        built = build_model(model, drives=self.drives) if isinstance(model, str) else model
        force_noise = [channel_noise(log.force) for log in self.logs]
        if any(t.needs_measured_force for t in built.terms):
            self.drives = [eqx.tree_at(lambda d: d.measured_force, d, (
                np.asarray if host else jnp.asarray)(
                smooth_force(log.force, log.time, noise=sigma)))
                for d, log, sigma in zip(self.drives, self.logs, force_noise)]
        fixed_values = ({k: v for k, v in fix.items() if v is not None}
                        if isinstance(fix, Mapping) else {})
        fixed_names = set(fix)
        self.fixed_nuisances = fixed_names & set(NUISANCES)
        model_fixed = fixed_names - set(NUISANCES)
        model_values = {k: v for k, v in fixed_values.items() if k in model_fixed}
        if model_values:
            built = Parameterization(built).with_values(built, model_values, where="--fix")
        self.model = built
        self.par = Parameterization(built, fixed=model_fixed)
        self.has_friction = bool(built.terms_of(FrictionBase))
        closed = any("closed" in d.modes for d in self.drives) and built.has("chamber")
        if "closing_pressure" in free and not closed:
            raise InputError(None, "--free closing_pressure",
                             "no log has a closed, modelled chamber",
                             "drop the option (logged pressures are used as they are)")
        applicable = {"offset": True, "friction_state0": self.has_friction,
                      "closing_pressure": "closing_pressure" in free}
        self.nuisance_names = [n for n in NUISANCES
                               if n not in self.fixed_nuisances and applicable[n]]
        self.force_noise = [max(sigma, _FORCE_NOISE_FLOOR) for sigma in force_noise]
        self.pressure_noise = [
            {c: max(channel_noise(p), _PRESSURE_NOISE_FLOOR)
             for c, p in (("a", log.pressure_a), ("b", log.pressure_b)) if p is not None}
            for log in self.logs]
        self.sample_weights = [
            selection.sample_weights(len(log), seg, where=log.path and str(log.path) or log.name)
            for log, seg in zip(self.logs, self.segmentations)]
        self._groups = build_groups(self.drives, self.logs, self.sample_weights, self.force_noise,
                                    self.pressure_noise, host=host)
        self._compiled: dict[tuple, Callable] = {}
        self._reversal_noise: tuple | None = None
        self.n_data = int(sum(int(np.count_nonzero(np.asarray(g.weight))) + sum(
            int(np.count_nonzero(np.asarray(w))) for w in g.pressure_weight if w is not None)
            for g in self._groups))
        self._frozen = True

    def __setattr__(self, name, value):
        if getattr(self, "_frozen", False):
            raise AttributeError(f"a Problem is immutable: cannot set '{name}' (build a new "
                                 "Problem with other logs, model or options)")
        object.__setattr__(self, name, value)

    # -- set-up ---------------------------------------------------------------------------
    @staticmethod
    def _want_denoise(denoise, seg: Segmentation, displacement) -> bool:
        if denoise == "auto":
            return seg.noise > 0.05e-6 or chatters(displacement, seg.reversals)
        return bool(denoise)

    @property
    def groups(self) -> tuple:
        """The stacks the logs run in (:class:`~fitstiff.inference.stacking.Group`: each a
        ``vmap``-ed scan over logs of one structure, padded to its longest)."""
        return tuple(self._groups)

    # -- the flat vector ------------------------------------------------------------------
    @property
    def n_logs(self) -> int:
        return len(self.logs)

    @property
    def names(self) -> list[str]:
        """Names of theta's entries: model parameters, then ``<nuisance>[<log name>]``."""
        return self.par.names + [f"{n}[{log.name}]" for n in self.nuisance_names
                                 for log in self.logs]

    @property
    def size(self) -> int:
        return self.par.size + len(self.nuisance_names) * self.n_logs

    def closing_pressure_start(self) -> np.ndarray:
        """Start values (Pa gauge) of the closing pressures: the rig's ``supply_bar``, else the
        first logged pressure of a closed chamber, else 5 bar."""
        out = []
        for log, drive in zip(self.logs, self.drives):
            value = log.rig.supply_pressure
            for c, chamber in enumerate("ab"):
                gauge = log.gauge(chamber)
                if value is None and drive.observed[c] and gauge is not None:
                    value = float(gauge[0])
            out.append(_DEFAULT_CLOSING_PA if value is None else value)
        return np.asarray(out)

    def pack(self, model: Model, nuisances: Mapping[str, Sequence[float]] | None = None):
        """theta from a model and per-log nuisance values (``offset`` in N,
        ``friction_state0`` in (-1, 1), ``closing_pressure`` in Pa gauge); missing offsets
        and states are 0, missing closing pressures :meth:`closing_pressure_start`."""
        parts = [np.asarray(self.par.to_unconstrained(model))]
        nuisances = dict(nuisances or {})
        nuisances.setdefault("closing_pressure", self.closing_pressure_start())
        for name in self.nuisance_names:
            values = np.asarray(nuisances.get(name, np.zeros(self.n_logs)), float)
            if name == "friction_state0":
                values = np.clip(values, -0.999, 0.999)     # a start off saturation
            parts.append(np.asarray(self.nuisance_param(name).inverse(values)))
        return jnp.asarray(np.concatenate(parts))

    def unpack(self, theta):
        """``(model, {nuisance: (n_logs,) values})`` for ``theta`` (differentiable)."""
        return self.par.to_model(theta[:self.par.size], self.model), self.nuisances(theta)

    def unpack_physical(self, values) -> tuple[Model, dict[str, np.ndarray]]:
        """:meth:`unpack` of the SI values :meth:`physical` returns: no transform is
        evaluated (NumPy in, NumPy out; the fit's summary has them from its compiled pass)."""
        values = np.asarray(values, dtype=float)
        model = self.par.physical_to_model(values[:self.par.size], self.model)
        off = self.par.size + self.n_logs * np.arange(len(self.nuisance_names))
        return model, {name: values[o:o + self.n_logs]
                       for name, o in zip(self.nuisance_names, off)}

    def nuisances(self, theta):
        """``{nuisance: (n_logs,) values}`` of ``theta`` (its entries after the model's)."""
        out, off = {}, self.par.size
        for name in self.nuisance_names:
            out[name] = self.nuisance_param(name).forward(theta[off:off + self.n_logs])
            off += self.n_logs
        return out

    def nuisance_param(self, name: str) -> Param:
        """The transform-layer entry of nuisance ``name``: one element per log."""
        return dataclasses.replace(NUISANCE_PARAMS[name], size=self.n_logs)

    def linear_entries(self) -> list[int]:
        """Positions in ``theta`` of the entries the residuals are exactly linear in: the
        per-log force offsets (added to the model force; the posterior integrates them out)."""
        if "offset" not in self.nuisance_names:
            return []
        start = self.par.size + self.nuisance_names.index("offset") * self.n_logs
        return list(range(start, start + self.n_logs))

    def log_jacobian(self, theta):
        """log |d(physical)/d(theta)|, the constant parts left out (the nuisances' with a
        :data:`~fitstiff.physics.params.CONSTANT_JACOBIAN` transform: offsets, closing
        pressures)."""
        lj = self.par.log_jacobian(theta[:self.par.size])
        for k, name in enumerate(self.nuisance_names):
            param = self.nuisance_param(name)
            if param.transform not in CONSTANT_JACOBIAN:
                off = self.par.size + k * self.n_logs
                lj = lj + param.log_jacobian(theta[off:off + self.n_logs])
        return lj

    def physical(self, theta):
        """SI values of every entry of ``theta``, in the order of :attr:`names` (model
        parameters through their transforms, offsets in N, initial states in (-1, 1))."""
        _, nuisances = self.unpack(theta)
        return jnp.concatenate([self.par.physical(theta[:self.par.size])]
                               + [nuisances[n] for n in self.nuisance_names])

    # -- evaluation -----------------------------------------------------------------------
    def residual_series(self, channels: Sequence[str] = CHANNELS) -> list[ResidualSeries]:
        """The layout of :meth:`residuals`: one entry per log and observed channel, in the
        order of the residual vector (:func:`~fitstiff.inference.stacking.residual_series`
        of the problem's groups); ``channels``: only those of :data:`CHANNELS` (the layout of
        ``residuals(..., channels=)``)."""
        return residual_series(self._groups, channels)

    def displacements(self) -> tuple:
        """The displacement each group drives the model with, ``(L, N)`` per group."""
        return tuple(g.drive.displacement for g in self._groups)

    @functools.cached_property
    def displacement_rho(self) -> list[float]:
        """Lag-1 correlation of each log's displacement noise, from
        :func:`~fitstiff.signal.noise.noise_floor` (``displacement_noise`` is its white-equivalent
        level; the marginal one is ``noise * marginal_scale(rho)``). Estimated on first use:
        only the turning points' errors and fit.json need it."""
        return [noise_floor(log.displacement).rho for log in self.logs]

    def reversal_noise(self) -> tuple:
        """Per group ``(L, N)``: the standard error (m) of each log's turning points at their
        samples, 0 elsewhere - the local fit's (:func:`~fitstiff.segments.denoise.turning_points`)
        for a denoised log, else the displacement noise. Both allow for correlated
        displacement noise (its lag-1 correlation from :func:`~fitstiff.signal.noise.noise_floor`):
        read as white, AR(1) noise of correlation 0.73 looks 2.2 times smaller than it is and
        the turning points' errors came out half the actual ones (``benchmarks/
        calibration.py`` datasets). An error in a turning point shifts the whole branch after
        it; this is the errors-in-variables part of the covariance
        (:mod:`fitstiff.inference.fitting`) and of the posterior's likelihood. Computed once, from
        the concrete drives (a :meth:`compiled` function receives them as arguments)."""
        if self._reversal_noise is not None:
            return self._reversal_noise
        out = []
        for g in self._groups:
            rows = []
            for i in g.index:
                row = np.zeros(g.force.shape[1])
                seg = self.segmentations[i]
                rho = self.displacement_rho[i]
                if self.denoised[i]:
                    # a denoised log's turning points are local fits: their own errors
                    index, _, error = turning_points(self.logs[i].displacement,
                                                     seg.reversals, noise=seg.noise, rho=rho,
                                                     still=seg.still)
                    row[index] = error
                else:
                    x = np.asarray(self.drives[i].displacement)
                    row[reversal_samples(x, seg.reversals)] = (self.displacement_noise[i]
                                                               * marginal_scale(rho))
                rows.append(row)
            out.append(rows[0][None] if self.chunked and len(rows) == 1
                       else np.stack(rows) if self.chunked else jnp.asarray(np.stack(rows)))
        object.__setattr__(self, "_reversal_noise", tuple(out))     # computed once, on demand
        return self._reversal_noise

    def _group_drive(self, group: Group, nuisances, displacement=None):
        drive = group.drive
        if displacement is not None:
            drive = drive.moved(displacement)
        return with_nuisances(drive, nuisances, jnp.asarray(group.index))

    def predictions(self, theta, displacements=None):
        """Per group: the vmap-ed :class:`~fitstiff.physics.model.Prediction` (leading log axis).
        ``displacements`` (shaped as :meth:`displacements`) replaces the model input."""
        return self.model_predictions(*self.unpack(theta), displacements)

    def residuals_physical(self, x, theta):
        """:meth:`residuals` with the model's free parameters given in SI (``x``, ordered as
        ``par.names``) instead of ``theta``'s unconstrained entries; ``theta`` supplies the
        nuisances. The path for score statistics at nulls on a bound
        (:meth:`~fitstiff.physics.params.Parameterization.physical_to_model`)."""
        model = self.par.physical_to_model(x, self.model)
        return self.model_residuals(model, self.nuisances(theta))

    def model_predictions(self, model, nuisances, displacements=None):
        """:meth:`predictions` of a given model and nuisance values."""
        displacements = displacements or (None,) * len(self._groups)
        return [jax.vmap(model.run)(self._group_drive(g, nuisances, x))
                for g, x in zip(self._groups, displacements)]

    def residuals(self, theta, displacements=None, *, channels: Sequence[str] = CHANNELS):
        """Whitened residual vector (model - data), padded entries exactly 0; ``channels``:
        only the series of those channels (:meth:`residual_series` with them)."""
        return self.model_residuals(*self.unpack(theta), displacements, channels=channels)

    def model_residuals(self, model, nuisances, displacements=None, *,
                        channels: Sequence[str] = CHANNELS, predictions=None):
        """:meth:`residuals` of a given model and nuisance values (``predictions``: their
        :meth:`model_predictions`, when the caller has them)."""
        if predictions is None:
            predictions = self.model_predictions(model, nuisances, displacements)
        return jnp.concatenate([_group_residuals(group, pred, channels)
                                for group, pred in zip(self._groups, predictions)])

    def weighted_residuals(self, x, theta, weights):
        """``residuals_physical(x, theta) * weights`` (``weights``: one per residual entry, at
        run time), where a stack whose entries all weigh 0 is not run: its part is 0. A
        held-out fold leaves a log out by its weights, and the longest log alone in its
        stack then costs nothing in the fold's solves (``lax.cond`` on the weights; under
        ``vmap`` both branches run)."""
        model = self.par.physical_to_model(x, self.model)
        nuisances = self.nuisances(theta)
        parts, start = [], 0
        for group in self._groups:
            size = group.force.size * (1 + sum(m is not None for m in group.pressure))
            w = weights[start:start + size]
            start += size

            def run(w, group=group):
                pred = jax.vmap(model.run)(self._group_drive(group, nuisances))
                return _group_residuals(group, pred, CHANNELS) * w

            parts.append(jax.lax.cond(jnp.any(w != 0), run, jnp.zeros_like, w))
        return jnp.concatenate(parts)

    def closing_pressures(self, theta):
        """``(n_logs, 2)``: each log's absolute pressure of chambers A and B at its first
        sample, as the model starts from it (the drive's, or the ``closing_pressure``
        nuisance's)."""
        nuisances = self.nuisances(theta)
        rows = [None] * self.n_logs
        for g in self._groups:
            drive = self._group_drive(g, nuisances)
            for row, i in enumerate(g.index):
                rows[i] = jnp.stack([drive.p_a0[row], drive.p_b0[row]])
        return jnp.stack(rows)

    @functools.cached_property
    def windows(self):
        """The windows a chunked problem is fitted in
        (:class:`~fitstiff.inference.chunks.Windows`)."""
        from fitstiff.inference.chunks import Windows

        return Windows(self)

    def per_log(self, theta) -> list[dict[str, np.ndarray]]:
        """Per log (in order): predicted force, per-term forces and pressures, unpadded (a
        chunked problem's window by window)."""
        if self.chunked:
            return self.windows.predict(jnp.asarray(theta))
        out: list[dict[str, np.ndarray] | None] = [None] * self.n_logs
        predictions = self.compiled(Problem.predictions)
        for group, pred in zip(self._groups, predictions(theta)):
            for row, i in enumerate(group.index):
                n = len(self.logs[i])
                out[i] = {"force": np.asarray(pred.force[row, :n]),
                          "contributions": np.asarray(pred.contributions[row, :n]),
                          "pressure_a": np.asarray(pred.pressure_a[row, :n]),
                          "pressure_b": np.asarray(pred.pressure_b[row, :n])}
        return out  # type: ignore[return-value]

    def unpad(self, per_group) -> list[np.ndarray]:
        """Per log (in order), unpadded: arrays given per group with a leading log axis (as
        :meth:`predictions` returns them)."""
        out: list[np.ndarray | None] = [None] * self.n_logs
        for group, values in zip(self._groups, per_group):
            values = np.asarray(values)
            for row, i in enumerate(group.index):
                out[i] = values[row, :len(self.logs[i])]
        return out  # type: ignore[return-value]

    @property
    def par_fixed(self) -> set[str]:
        """Model parameter names held fixed."""
        free = set(self.par.names)
        return {n for _, _, names in named_params(self.model) for n in names} - free

    def par_unit(self, name: str) -> str:
        return find_param(self.model, name).unit

    def compiled(self, fn: Callable, /, **options) -> Callable:
        """``fn(problem, *args, **options)`` compiled for this problem, as ``f(*args)``.

        ``fn`` is a module-level function (or a method of :class:`Problem`) that reaches the
        data only through its ``problem`` argument; ``options`` are static (hashable) values
        it is specialised on (a solver's tolerances, a noise model). It is compiled with
        ``jax.jit``, the arguments split as ``equinox.filter_jit`` does (arrays traced, other
        leaves static and hashable), and this problem's data arrays (the stacked drives,
        measurements and weights, the turning-point errors) passed to the executable as
        arguments: a function closing over the problem would compile them in as constants, a
        copy per function that XLA copies again while compiling (``benchmarks/fit_memory.py``:
        about 600 MB more peak for the solve of a 1 M-sample log).

        **One compilation per structure.** Problems of one structure (:meth:`structure_key`:
        the same model and fixed values, nuisances, log lengths and channels, array shapes)
        share one compiled executable per ``(fn, options)``: a fleet's cylinders, the
        diagnosis' folds and candidate refits compile once, not once per problem (a
        ``chamber+dahl`` fit of two 3 700-sample logs: about 5 s of its 5.4 s are the two
        compilations). The shared function keeps no problem alive: it is traced with the
        problem that calls it, whose data are arguments, and only ``fn``'s static structure
        is part of it. Anything else ``fn`` could read off the problem that differs between
        problems of one structure is part of the key.
        """
        key = (fn, tuple(sorted(options.items())))
        if key not in self._compiled:
            self._compiled[key] = compile_for(self, fn, options)
        return self._compiled[key]

    def structure_key(self, leaves=None, tree=None, structure=None) -> tuple | None:
        """What a function compiled for this problem depends on besides its data arrays
        (:func:`~fitstiff.inference.compiling.structure_key`). Two problems with equal keys
        share compiled functions (:meth:`compiled`); a fleet batches cylinders of one key
        (:mod:`fitstiff.fleet`)."""
        return structure_key(self, leaves, tree, structure)

    def data_arrays(self):
        """The arrays a compiled function receives as arguments (:meth:`compiled`): the
        stacked groups, the drives and the turning points' errors."""
        # a drive's name labels messages only: problems that differ in their logs' names
        # alone share compiled functions (:meth:`structure_key`)
        drives = [dataclasses.replace(d, name="") if d.name else d for d in self.drives]
        return self._groups, drives, self.reversal_noise()

    def with_data_arrays(self, arrays) -> Problem:
        """A copy whose data arrays are ``arrays`` (the traced arguments of :meth:`compiled`)."""
        bound = copy.copy(self)
        for name, value in zip(("_groups", "drives", "_reversal_noise"), arrays):
            object.__setattr__(bound, name, value)
        return bound


def _group_residuals(group: Group, pred, channels: Sequence[str]):
    """The whitened residual entries of one stack (force, then the observed pressures)."""
    parts = []
    if "force" in channels:
        parts.append(((pred.force - group.force) * group.weight).ravel())
    for c, measured in enumerate(group.pressure):
        if measured is None or CHANNELS[1 + c] not in channels:
            continue
        modelled = pred.pressure_a if c == 0 else pred.pressure_b
        parts.append(((modelled - measured) * group.pressure_weight[c]).ravel())
    return jnp.concatenate(parts)


def with_nuisances(drive: Drive, nuisances: Mapping[str, jnp.ndarray], index) -> Drive:
    """``drive`` with the nuisance values (:meth:`Problem.nuisances`) of the logs at
    ``index`` (an array for a stack of drives, an integer for one): force offset, initial
    friction state, closing pressure."""
    if "offset" in nuisances:
        drive = eqx.tree_at(lambda d: d.force_offset, drive, nuisances["offset"][index])
    if "friction_state0" in nuisances:
        drive = eqx.tree_at(lambda d: d.friction_state0, drive,
                            nuisances["friction_state0"][index])
    if "closing_pressure" in nuisances:
        p0 = drive.p_amb + nuisances["closing_pressure"][index]
        drive = eqx.tree_at(lambda d: (d.p_a0, d.p_b0), drive, (p0, p0))
    return drive


def _rows(logs: Sequence[Log]) -> int:
    """The residual vector's length at most: each log's samples times its logged channels."""
    return sum(len(log) * (1 + (log.pressure_a is not None) + (log.pressure_b is not None))
               for log in logs)


def _segmentations(logs: Sequence[Log], given: Sequence[Segmentation] | None
                   ) -> list[Segmentation]:
    """``given`` checked against ``logs`` (one per log, of its length), or ``segment(log)``."""
    if given is None:
        return [segment(log) for log in logs]
    given = list(given)
    if len(given) != len(logs):
        raise InputError(None, "segmentations", f"{len(given)} given for {len(logs)} logs",
                         "give one Segmentation per log, in the order of the logs")
    for log, seg in zip(logs, given):
        if not isinstance(seg, Segmentation) or len(seg.still) != len(log):
            found = (type(seg).__name__ if not isinstance(seg, Segmentation)
                     else f"one of {len(seg.still)} samples")
            raise InputError(log.path and str(log.path) or log.name, "segmentation",
                             f"found {found} for a log of {len(log)} samples",
                             "give the Segmentation of this log (fitstiff.segment(log))")
    return given


