"""Composition: a model is a sum of terms, run as one compiled ``lax.scan`` over the samples
(terms with a closed form over all samples at once).

>>> from fitstiff.physics.model import build_model
>>> model = build_model("dahl+viscous")
>>> model.spec
'dahl+viscous'

``Model.predict(drive)`` returns the predicted force (N) for every sample of a
:class:`~fitstiff.physics.drive.Drive`; ``Model.contributions(drive)`` the force of each
force-giving term. Both are pure JAX: differentiable in every parameter, usable under ``jit`` and
``vmap`` (over a batch of models built with :class:`~fitstiff.physics.params.Parameterization`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import NamedTuple

import equinox as eqx

from fitstiff._jax import jax, jnp
from fitstiff.errors import InputError
from fitstiff.io.log import Log
from fitstiff.io.validation import parse_decimal
from fitstiff.physics.drive import Drive, drive_from_log
from fitstiff.physics.params import find_param, named_params
from fitstiff.physics.terms import (TERMS, Chamber, ForceSource, InputTerm, Modifier, Modulation,
                                    SeriesTerm, Step, Term)

__all__ = ["Model", "Needs", "Prediction", "build_model", "parse_spec", "model_for_logs",
           "model_needs", "parse_fix", "DEFAULT_MODEL", "time_steps", "difference_acceleration"]

#: the model of the paper's cylinder and every command's default: the chamber's gas spring and a
#: Dahl pre-sliding spring
DEFAULT_MODEL = "chamber+dahl"

_NEWTON_STEPS = 4


def parse_spec(spec: str) -> list[tuple[str, str | None]]:
    """``"chamber+maxwell_slip:4"`` -> ``[("chamber", None), ("maxwell_slip", "4")]``."""
    if not isinstance(spec, str) or not spec.strip():
        raise InputError(None, "model spec", f"found {spec!r}",
                         "give terms joined by '+', e.g. 'chamber+dahl'")
    out = []
    for token in spec.replace(" ", "").split("+"):
        name, _, arg = token.partition(":")
        if name not in TERMS:
            raise InputError(None, f"model spec '{spec}'", f"unknown term '{name}'",
                             f"use terms from: {', '.join(TERMS)}")
        if any(name == seen for seen, _ in out):
            raise InputError(None, f"model spec '{spec}'", f"term '{name}' appears twice",
                             "name each term once")
        out.append((name, arg or None))
    return out


class Prediction(NamedTuple):
    """Everything a model predicts for one drive (arrays over the samples)."""

    force: jnp.ndarray          # (n,) N, total measured force incl. the drive's offset
    contributions: jnp.ndarray  # (n, n_force_terms) N, see Model.force_names
    pressure_a: jnp.ndarray     # (n,) Pa abs: modelled (closed), logged (measured) or ambient
    pressure_b: jnp.ndarray


def time_steps(t):
    """``(dt, dt_mid)``: each sample's step from the previous one (the first mirrors the
    second) and the mean of the steps either side (the last repeats)."""
    dt = jnp.diff(t, prepend=2 * t[0] - t[1])
    return dt, 0.5 * (dt + jnp.append(dt[1:], dt[-1]))


def difference_acceleration(v, dt_mid):
    """The forward difference of the velocity ``v`` over ``dt_mid``."""
    return jnp.diff(v, append=v[-1]) / dt_mid


class Model(eqx.Module):
    """An immutable sum of terms. Build it with :func:`build_model`."""

    terms: tuple[Term, ...]

    def __check_init__(self):
        names = [t.name for t in self.terms]
        spec = "+".join(names)
        for t in self.terms_of(Modifier):
            if not self.terms_of(t.targets):
                wanted = t.targets.described
                raise InputError(None, f"model spec '{spec}'",
                                 f"'{t.name}' modifies {wanted} but the model has none",
                                 f"add {wanted}")
        if "lugre" in names and "stribeck" in names:
            raise InputError(None, f"model spec '{spec}'",
                             "'lugre' already contains the Stribeck curve (Fs, vs)",
                             "drop 'stribeck'")
        if not self.terms_of(ForceSource):
            raise InputError(None, f"model spec '{spec}'", "has no term that gives a force",
                             "add chamber, a friction base or a force term")

    # -- structure --------------------------------------------------------------------------
    def settings(self) -> dict[str, dict[str, object]]:
        """Static (structural) fields of every term that has any, by term name, e.g.
        ``{"pressure_friction": {"p_ref": 300000.0}}`` (Pa): what a parameter is relative to."""
        out = {}
        for term in self.terms:
            static = {f.name: getattr(term, f.name) for f in dataclasses.fields(term)
                      if f.metadata.get("static", False) and f.metadata.get("setting", True)}
            if static:
                out[term.name] = static
        return out

    @property
    def spec(self) -> str:
        """The spec that builds this model's structure again (term tokens with their
        arguments: ``chamber+maxwell_slip:6``)."""
        return "+".join(t.token for t in self.terms)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(t.name for t in self.terms)

    def with_terms(self, terms) -> Model:
        return Model(tuple(terms))

    def term(self, name: str) -> Term:
        for t in self.terms:
            if t.name == name:
                return t
        raise KeyError(name)

    def has(self, name: str) -> bool:
        return name in self.names

    def terms_of(self, *roles: type[Term]) -> list[Term]:
        """The terms that are instances of any of ``roles`` (e.g. ``FrictionBase``), in
        order."""
        return [t for t in self.terms if isinstance(t, roles)]

    @property
    def force_names(self) -> tuple[str, ...]:
        """Names of the terms whose forces :meth:`contributions` returns (in order)."""
        return tuple(t.name for t in self.terms_of(ForceSource))

    @property
    def needs_chamber(self) -> bool:
        """Whether drives need the rig values of the chamber force."""
        return bool(self.terms_of(Chamber))

    def closed_form_chamber(self) -> Chamber | None:
        """The chamber term when its modelled pressures are the closed form ``p0 * (V(x[0]) /
        V(x))**n`` of the drive's displacement
        (:meth:`~fitstiff.physics.terms.chamber.Chamber.run_all`, as :meth:`run` evaluates it): no
        modifier acts on the chamber, no series compliance couples it to the force, no input term
        transforms the displacement. None otherwise (and without a chamber)."""
        chambers = self.terms_of(Chamber)
        if (not chambers or self.terms_of(SeriesTerm) or self.terms_of(InputTerm)
                or any(isinstance(chambers[0], m.targets) for m in self.terms_of(Modifier))):
            return None
        return chambers[0]

    # -- evaluation -------------------------------------------------------------------------
    def steps(self, drive: Drive, *, tie=None) -> Step:
        """Per-sample scan inputs (after input terms such as the time delay).

        ``tie``: for a window of a log with margins (:meth:`run_window`), ``(i, j, a, b)`` per
        sample: its displacement is ``a x[i] + b x[j]`` of the window's samples (itself inside
        the log; before the log's first sample that sample, held; after its last one more
        step of the last increment, then held). The input terms then see the log's ends held,
        as on the whole log, and their output is tied the same way, so a shift that reads
        ahead does not carry later samples into the margin before the log (the first step
        moved the state there: 0.094 N apart from the whole log at a delay of -3.3 ms)."""
        x = drive.displacement
        inputs = self.terms_of(InputTerm)
        if tie is not None and inputs:
            i, j, a, b = tie
            x = x[i]
        for term in inputs:
            x = term.transform_input(drive, x)
        if tie is not None and inputs:
            x = a * x[i] + b * x[j]
        t = drive.time
        dt, dt_mid = time_steps(t)
        dx = jnp.diff(x, prepend=x[0])
        if drive.velocity is None:
            v = dx / dt
        else:
            # the smoothed velocity of the measured displacement, plus the rate of what the
            # input terms change (zero at their null: a time delay of 0 or a compliance of 0
            # leaves the smoothed velocity as it is)
            shift = x - drive.displacement
            v = drive.velocity + jnp.diff(shift, prepend=shift[0]) / dt
        if drive.acceleration is None:
            a = difference_acceleration(v, dt_mid)
        else:
            # the smoothed acceleration of the measured displacement, without the input
            # terms' change: a compliance's is the second difference of the measured force,
            # whose own noise would enter the prediction (measured: with it, inertia plus
            # rig_compliance:measured fitted the inertia set's noise, held-out RMS 0.183 N
            # below its 0.2 N noise); a time delay's is a shift of a smooth signal
            a = drive.acceleration
        return Step(t=t, dt=dt, x=x, dx=dx, v=v, a=a, p_a=drive.pressure_a,
                    p_b=drive.pressure_b, still=drive.still)

    def _stepper(self, drive: Drive, scanned: Sequence[ForceSource]):
        """The scan body stepping the modifiers and the force sources ``scanned`` (with the
        Newton iteration of a series compliance): ``body((states, x_piston), step) ->
        ((states, x_piston), (forces, p_a, p_b))``."""
        modifiers = self.terms_of(Modifier)
        series = self.terms_of(SeriesTerm)
        chamber = next((t for t in scanned if isinstance(t, Chamber)), None)

        def evaluate(states, s):
            mod_states, force_states = states
            mod = Modulation()
            new_mod = []
            for term, st in zip(modifiers, mod_states):
                st, m = term.modulate(st, s, drive)
                new_mod.append(st)
                mod = mod.combine(m)
            new_force, forces = [], []
            for term, st in zip(scanned, force_states):
                st, f = term.step(st, s, drive, mod)
                new_force.append(st)
                forces.append(f)
            if chamber is None:
                p = (drive.p_amb, drive.p_amb)
            else:
                p = chamber.pressures(new_force[scanned.index(chamber)], s, drive)
            return (tuple(new_mod), tuple(new_force)), (jnp.stack(forces), *p)

        def body(carry, s):
            states, x_piston = carry
            if not series:
                new_states, out = evaluate(states, s)
                return (new_states, x_piston), out
            # x_piston = x_sensor - compliance * F: Newton on the piston increment
            c = series[0].compliance

            def at(dxp):
                s_p = s._replace(x=x_piston + dxp, dx=dxp, v=dxp / s.dt)
                return evaluate(states, s_p)

            def total(dxp):
                return jnp.sum(at(dxp)[1][0])

            dxp = s.x - c * jax.lax.stop_gradient(total(0.0)) - x_piston
            for _ in range(_NEWTON_STEPS):
                f, dfdx = jax.jvp(total, (dxp,), (jnp.ones_like(dxp),))
                dxp = dxp - (x_piston + dxp + c * f - s.x) / (1.0 + c * dfdx)
            new_states, out = at(dxp)
            return (new_states, x_piston + dxp), out

        return body

    def _initial(self, drive: Drive, scanned: Sequence[ForceSource], x0):
        """The scan's carry at the drive's first sample (``x0``: the piston's position)."""
        return ((tuple(t.init(drive) for t in self.terms_of(Modifier)),
                 tuple(t.init(drive) for t in scanned)), x0)

    def _input_free(self, drive: Drive) -> Drive:
        """``drive`` without the runs and the chamber span where input terms transform the
        displacement (they are the drive's displacement's, not the transformed one's)."""
        if self.terms_of(InputTerm):
            return dataclasses.replace(drive, runs=None, log_volume_span=None,
                                       log_volume_ratios=None)
        return drive

    def run(self, drive: Drive) -> Prediction:
        """Run the scan: total force, per-term forces and the chamber pressures.

        Terms that no modifier acts on are evaluated over all samples at once when they can be
        (:meth:`~fitstiff.physics.terms.base.Term.run_all`: stateless terms, the polytropic chamber,
        Dahl over the drive's monotone runs), unless a series compliance couples every term to
        the piston motion; only the rest is stepped in the ``lax.scan``. The results are the
        same; the scan body is smaller (under ``vmap`` over the posterior's walkers its
        per-step cost dominates).
        """
        modifiers = self.terms_of(Modifier)
        forcing = self.terms_of(ForceSource)
        steps = self.steps(drive)
        drive = self._input_free(drive)
        targeted = tuple(m.targets for m in modifiers)
        direct = {}
        if not self.terms_of(SeriesTerm):
            for i, term in enumerate(forcing):
                out = None if isinstance(term, targeted) else term.run_all(steps, drive)
                if out is not None:
                    direct[i] = out
        scanned = [t for i, t in enumerate(forcing) if i not in direct]
        n = steps.x.shape[0]
        p_a = p_b = drive.p_amb
        columns = {}
        if scanned:
            _, (stepped, p_a, p_b) = jax.lax.scan(self._stepper(drive, scanned),
                                                  self._initial(drive, scanned, steps.x[0]),
                                                  steps)
            columns = {forcing.index(t): stepped[:, k] for k, t in enumerate(scanned)}
        for i, (states, force) in direct.items():
            columns[i] = jnp.broadcast_to(force, (n,))
            if isinstance(forcing[i], Chamber):
                p_a, p_b = forcing[i].pressures(states, steps, drive)
        return self._prediction(drive, [columns[i] for i in range(len(forcing))], p_a, p_b, n)

    def run_window(self, drive: Drive, carry=None, *, start: int, length: int, tie=None
                   ) -> tuple[Prediction, object]:
        """Step every force source over the samples ``[start, start + length)`` of ``drive``
        from the scan state ``carry`` (``None``: the initial state at sample ``start``), and
        return their prediction with the state after them.

        A long log runs as consecutive windows of this (:mod:`fitstiff.inference.chunks`):
        ``drive`` is a stretch of the log with margins around the window (samples that the
        per-sample inputs read: the previous sample's displacement and time, the next one's
        velocity, an input term's reach, :meth:`reach`), and the state is carried from one
        window to the next. Stepping everything (no closed form over all samples) is the same
        law; the results equal :meth:`run`'s on the whole log up to rounding. ``tie``: how
        the margins' displacements are made of the log's samples (:meth:`steps`).
        """
        forcing = self.terms_of(ForceSource)
        steps = self.steps(drive, tie=tie)
        drive = self._input_free(drive)
        window = jax.tree.map(lambda a: jax.lax.slice_in_dim(a, start, start + length), steps)
        if carry is None:
            carry = self._initial(drive.window(start), forcing, window.x[0])
        carry, (stepped, p_a, p_b) = jax.lax.scan(self._stepper(drive, forcing), carry, window)
        prediction = self._prediction(drive, [stepped[:, k] for k in range(len(forcing))],
                                      p_a, p_b, length)
        return prediction, carry

    def reach(self, dt: float) -> int:
        """Samples before and after a window that :meth:`run_window` reads to step it at the
        sampling interval ``dt`` (s): one either side (differences), plus what an input term
        reads (:meth:`~fitstiff.physics.terms.base.InputTerm.reach_s`)."""
        seconds = max((t.reach_s() for t in self.terms_of(InputTerm)), default=0.0)
        return 2 + (math.ceil(seconds / dt) if seconds > 0 else 0)

    @staticmethod
    def _prediction(drive: Drive, columns, p_a, p_b, n: int) -> Prediction:
        forces = jnp.stack(columns, axis=1)
        return Prediction(force=jnp.sum(forces, axis=1) + drive.force_offset,
                          contributions=forces, pressure_a=jnp.broadcast_to(p_a, (n,)),
                          pressure_b=jnp.broadcast_to(p_b, (n,)))

    def contributions(self, drive: Drive) -> jnp.ndarray:
        """Force of each term in :attr:`force_names`, shape ``(n_samples, n_force_terms)``."""
        return self.run(drive).contributions

    def predict(self, drive: Drive) -> jnp.ndarray:
        """Predicted measured force (N) at every sample, including the drive's offset."""
        return self.run(drive).force


def build_model(spec: str, *, drives: Sequence[Drive] = ()) -> Model:
    """A model from a spec string such as ``"chamber+dahl"``, ``"chamber+maxwell_slip:4"``.

    ``drives``: the data the model will see; terms whose structure depends on it use it (the
    chamber fits ``n`` only if some chamber is closed; ``pressure_friction`` takes its reference
    pressure from the logs).
    """
    return Model(tuple(TERMS[name].from_spec(arg, drives=drives)
                       for name, arg in parse_spec(spec)))


class Needs(NamedTuple):
    """The rig data a model's terms declare they need
    (:class:`~fitstiff.physics.terms.base.Term`)."""

    chamber_geometry: bool   # the chamber's rig values (bore; stroke, start, supply if closed)
    acceleration: bool       # an acceleration (smoothed when the displacement is denoised)


def model_needs(model: str | Model) -> Needs:
    """What the terms of ``model`` (a spec string or a built model) need of the rig data."""
    terms = (model.terms if isinstance(model, Model)
             else [TERMS[name] for name, _ in parse_spec(model)])
    return Needs(chamber_geometry=any(t.needs_chamber_geometry for t in terms),
                 acceleration=any(t.needs_acceleration for t in terms))


def model_for_logs(spec: str, logs: Sequence[Log], *, still=None) -> tuple[Model, list[Drive]]:
    """The model of ``spec`` and one drive per log, checking the rig values it needs."""
    needs = model_needs(spec)
    drives = [drive_from_log(log, needs_chamber=needs.chamber_geometry,
                             still=None if still is None else still[i],
                             what=f"model '{spec}'") for i, log in enumerate(logs)]
    return build_model(spec, drives=drives), drives


def parse_fix(items: Sequence[str], spec: str) -> dict[str, float | None]:
    """Held parameters from ``--fix`` entries: ``["n=1.4", "offset"]`` -> ``{"n": 1.4,
    "offset": None}`` (values in the parameter's display unit, returned in SI; None: hold the
    start value). Raises :class:`InputError` naming the entry for a value that is not a
    number or a name that is not a parameter of ``spec`` (listing the names that are)."""
    model = build_model(spec)
    values: dict[str, float | None] = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep:
            values[name] = None
            continue
        number = parse_decimal(value)
        if number is None or not math.isfinite(number):
            raise InputError(None, f"--fix {item}", f"value {value!r} is not a number",
                             "write NAME=VALUE in the parameter's display unit, as a plain "
                             "finite decimal") from None
        try:
            param = find_param(model, name)
        except KeyError:
            names = [n for _, _, flat in named_params(model) for n in flat]
            raise InputError(None, f"--fix {item}", f"'{name}' is not a parameter of "
                             f"'{spec}'", f"use one of: {', '.join(names)} (NAME=VALUE), or "
                             "offset, friction_state0 (held at their start)") from None
        values[name] = param.to_si(number)
    return values
