"""The flow of a model as the shooting problems use it: counted
evaluations and one derivative API (Jacobian-vector products, monodromy,
``d/dT`` and ``d/dp``) over a model's own ``flow`` or the engine's
:class:`~contfil.engine.flows.radau.RadauFlow`.

A model that offers the exact tangent of its flow (the optional
``flow_tangent`` hook of :mod:`contfil.protocol`, probed once here) gets
all derivatives from one *sweep* (``phi``, the monodromy, ``d/dT``,
``d/dp`` and optional period samples), cached for the last ``(u, p, T)``."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from contfil.engine.flows.radau import RadauFlow
from contfil.engine.problems.base import fd_step
from contfil.errors import ConvergenceError, NonFiniteError
from contfil.protocol import FlowTangent, flow_tangent_hook

__all__ = ["FlowOps", "flow_ops"]

Array = NDArray[np.float64]


class FlowOps:
    """The flow of a model with counted evaluations and a uniform derivative API.

    Uses ``model.flow`` (and ``model.flow_jvp``) when present; otherwise a
    :class:`RadauFlow` built from ``rhs``/``jacobian``. ``flow_evals`` counts
    calls of the time-stepper (a finite-difference ``jvp`` costs one; an
    exact tangent of the default flow costs none once the base trajectory is
    cached, and ``tangent_evals`` counts those separately).

    ``flow_kwargs`` are passed to a model's own ``flow`` (e.g. ``{"steps":
    1000}`` for a stepper that wants its resolution); ``fd_rel`` sets the
    finite-difference increment (raise it for a stepper whose result is only
    accurate to its nonlinear-solver tolerance); ``fd_central`` switches to
    central differences (two flows per product, O(ε²) truncation error; pair
    it with a larger ``fd_rel``, e.g. 1e-5).

    ``flow_steps`` fixes the step count of a model's own fixed-step flow:
    passed as ``steps=`` to its ``flow`` *and* its ``flow_tangent`` (the
    tangent stays exact; multiple shooting places its segments on step
    boundaries this way). For the default flow it is the Radau step count.
    """

    def __init__(
        self,
        model: Any,
        steps: int = 100,
        fd_rel: float = 1e-7,
        param_index: int | None = None,
        flow_kwargs: dict[str, Any] | None = None,
        fd_central: bool = False,
        flow_steps: int | None = None,
    ) -> None:
        self.model = model
        self.flow_steps = None if flow_steps is None else int(flow_steps)
        self.fd_central = bool(fd_central)
        self.param_index = param_index
        self.fd_rel = float(fd_rel)
        self.flow_evals = 0
        self.tangent_evals = 0
        #: exact tangent sweeps of a model's ``flow_tangent`` hook
        self.tangent_sweeps = 0
        #: sweeps that failed (finite differences were used there instead)
        self.sweep_failures = 0
        self._failed: tuple[bytes, bytes, float] | None = None
        #: states per period returned with each sweep (period means)
        self.samples = 0
        own = getattr(model, "flow", None)
        self.radau: RadauFlow | None = None
        self._tangent = None
        self._sweep: tuple[tuple[bytes, bytes, float], FlowTangent] | None = None
        if callable(own):
            kw = dict(flow_kwargs or {})
            if self.flow_steps is not None:
                kw["steps"] = self.flow_steps
            self._flow = (lambda u, p, T: own(u, p, T, **kw)) if kw else own
            self._flow_jvp = getattr(model, "flow_jvp", None)
            # probed once: the engine never looks for hooks in its loops
            hook = flow_tangent_hook(model)
            if self.flow_steps is not None and hook is not None and set(kw) == {"steps"}:
                n = self.flow_steps
                self._tangent = (lambda u, p, T, V, k, s: hook(u, p, T, V, k, s, steps=n))
            else:
                self._tangent = None if kw else hook
        else:
            jac = getattr(model, "jacobian", None)
            self.radau = RadauFlow(model.rhs, jac if callable(jac) else None,
                                   steps=steps if self.flow_steps is None else self.flow_steps)
            self.radau.param_index = param_index
            self._flow = self.radau.flow_and_tangents
            self._flow_jvp = None
        self._last: tuple[tuple[bytes, bytes, float], Array] | None = None

    @property
    def exact_tangent(self) -> bool:
        """True when ``jvp`` is an exact derivative (default flow, model.flow_jvp
        or the model's ``flow_tangent`` sweep)."""
        return self.radau is not None or self._flow_jvp is not None or self.has_sweep

    @property
    def has_sweep(self) -> bool:
        """True when the model offers ``flow_tangent`` (exact batched tangents)."""
        return self._tangent is not None

    @staticmethod
    def _key(u: Array, p: Array, T: float) -> tuple[bytes, bytes, float]:
        return (np.asarray(u, float).tobytes(), np.asarray(p, float).tobytes(), float(T))

    def cached_sweep(self, u: Array, p: Array, T: float) -> FlowTangent | None:
        """The sweep at exactly ``(u, p, T)`` if it was computed last, else None."""
        if self._sweep is not None and self._sweep[0] == self._key(u, p, T):
            return self._sweep[1]
        return None

    def sweep(self, u: Array, p: Array, T: float) -> FlowTangent:
        """One exact tangent sweep at ``(u, p, T)``: ``phi``, the monodromy
        (``jvp``), ``dT``, ``dp`` (``param_index``) and ``samples`` states
        per period (cached for the last point)."""
        if self._tangent is None:
            raise ValueError("FlowOps.sweep: the model has no flow_tangent hook")
        got = self.cached_sweep(u, p, T)
        if got is not None:
            return got
        self.tangent_sweeps += 1
        ft = self._tangent(np.asarray(u, float), np.asarray(p, float), float(T), None,
                           self.param_index, self.samples)
        if not (np.all(np.isfinite(ft.phi)) and np.all(np.isfinite(ft.jvp))):
            name = getattr(self.model, "name", "?")
            raise NonFiniteError(f"flow_tangent of model {name!r} returned NaN/inf")
        key = self._key(u, p, T)
        self._sweep = (key, ft)
        self._last = (key, np.array(ft.phi, dtype=float))
        return ft

    def adopt_sweep(self, u: Array, p: Array, T: float) -> None:
        """Let the last sweep stand for ``(u, p, T)`` too: for a caller whose
        point moved by no more than its corrector tolerance since the sweep
        (the derivatives then differ at that level). ``flow`` is unaffected."""
        if self._sweep is not None:
            self._sweep = (self._key(u, p, T), self._sweep[1])

    def _try_sweep(self, u: Array, p: Array, T: float) -> FlowTangent | None:
        """:meth:`sweep`, or None where the model's stepper had no smooth
        tangent (e.g. a step it had to rescue): the caller then falls back to
        finite differences of the flow at that point."""
        if self._tangent is None:
            return None
        key = self._key(u, p, T)
        if self._failed == key:
            return None
        try:
            return self.sweep(u, p, T)
        except ConvergenceError:
            self.sweep_failures += 1
            self._failed = key
            return None

    def tangent_block(self, u: Array, p: Array, T: float, V: Array) -> Array:
        """``Dφ_T(u) V`` for the columns of ``V`` by one exact sweep (no
        caching; finite differences where the sweep fails)."""
        if self._tangent is None:
            raise ValueError("FlowOps.tangent_block: the model has no flow_tangent hook")
        self.tangent_sweeps += 1
        try:
            ft = self._tangent(np.asarray(u, float), np.asarray(p, float), float(T),
                               np.asarray(V, float), None, 0)
        except ConvergenceError:
            self.sweep_failures += 1
            return np.column_stack([self._fd_jvp(u, p, T, v, 0.0) for v in np.asarray(V).T])
        return np.asarray(ft.jvp, dtype=float)

    def flow(self, u: Array, p: Array, T: float) -> Array:
        """``φ_T(u)`` (memoised on the last call, so a residual and its jvp share it)."""
        key = self._key(u, p, T)
        if self._last is not None and self._last[0] == key:
            return self._last[1].copy()
        self.flow_evals += 1
        out = np.asarray(self._flow(np.asarray(u, float), p, float(T)), dtype=float)
        if not np.all(np.isfinite(out)):
            name = getattr(self.model, "name", "?")
            raise NonFiniteError(f"flow of model {name!r} returned NaN/inf")
        self._last = (key, out)
        return out.copy()

    def jvp(self, u: Array, p: Array, T: float, v: Array, dT: float = 0.0) -> Array:
        """``Dφ_T(u) v + ∂_T φ_T(u) dT``."""
        if self.radau is not None:
            self.flow(u, p, T)  # make sure the base trajectory is cached (and counted)
            self.tangent_evals += 1
            return self.radau.flow_jvp(u, p, T, v, dT)
        ft = self._try_sweep(u, p, T)
        if ft is not None:
            out = ft.jvp @ np.asarray(v, float)
            return out + dT * ft.dT if dT != 0.0 else out
        if self._flow_jvp is not None and dT == 0.0:
            self.tangent_evals += 1
            return np.asarray(self._flow_jvp(u, p, T, v), dtype=float)
        return self._fd_jvp(u, p, T, v, dT)

    def _fd_jvp(self, u: Array, p: Array, T: float, v: Array, dT: float) -> Array:
        """``Dφ_T(u) v + ∂_T φ dT`` by finite differences of the flow."""
        base = self.flow(u, p, T)
        z = np.concatenate([u, [T]])
        dv = np.concatenate([v, [dT]])
        eps = fd_step(z, dv, self.fd_rel)
        if eps == 0.0:
            return np.zeros_like(base)
        if self.fd_central:
            # O(ε²) truncation instead of O(ε): two flows per product
            self.flow_evals += 2
            fp = np.asarray(self._flow(u + eps * v, p, T + eps * dT), dtype=float)
            fm = np.asarray(self._flow(u - eps * v, p, T - eps * dT), dtype=float)
            return (fp - fm) / (2 * eps)
        self.flow_evals += 1
        pert = np.asarray(self._flow(u + eps * v, p, T + eps * dT), dtype=float)
        return (pert - base) / eps

    def dflow_dT(self, u: Array, p: Array, T: float) -> Array:
        """``∂_T φ_T(u)``: exact for the default flow and a sweep, ``f(φ_T(u))`` otherwise.

        For a model's own stepper, ``f`` at the end point is the derivative of
        the exact flow; it avoids a finite difference in ``T`` (a fixed-step
        stepper changes its step size with ``T``).
        """
        if self.radau is not None:
            return self.jvp(u, p, T, np.zeros_like(u), 1.0)
        ft = self._try_sweep(u, p, T)
        if ft is not None:
            return np.array(ft.dT, dtype=float)
        return np.asarray(self.model.rhs(self.flow(u, p, T), p), dtype=float)

    def dflow_dp(self, u: Array, p: Array, T: float) -> Array:
        """``∂φ_T(u)/∂p[param_index]``: exact for the default flow and a sweep, central
        differences of the model's flow otherwise (two flow evaluations)."""
        k = self.param_index
        if k is None:
            raise ValueError("FlowOps.dflow_dp: no param_index given")
        if self.radau is not None:
            self.flow(u, p, T)
            return self.radau.dflow_dp(u, p, T)
        ft = self._try_sweep(u, p, T)
        if ft is not None:
            return np.array(ft.dp, dtype=float)
        h = 1e-6 * (1.0 + abs(float(p[k])))
        pp, pm = np.array(p, dtype=float), np.array(p, dtype=float)
        pp[k] += h
        pm[k] -= h
        self.flow_evals += 2
        fp = np.asarray(self._flow(np.asarray(u, float), pp, float(T)), dtype=float)
        fm = np.asarray(self._flow(np.asarray(u, float), pm, float(T)), dtype=float)
        return (fp - fm) / (2 * h)

    def monodromy(self, u: Array, p: Array, T: float) -> Array:
        """Dense ``Dφ_T(u)`` (exact for the default flow and a sweep; ``n`` jvps otherwise)."""
        if self.radau is not None:
            self.flow(u, p, T)
            return self.radau.monodromy(u, p, T)[0]
        ft = self._try_sweep(u, p, T)
        if ft is not None:
            return np.array(ft.jvp, dtype=float)
        n = np.asarray(u).size
        return np.column_stack([self.jvp(u, p, T, e) for e in np.eye(n)])


def flow_ops(model: Any, steps: int = 100, param_index: int | None = None) -> FlowOps:
    """:class:`FlowOps` for ``model`` (its own flow if it has one)."""
    return FlowOps(model, steps=steps, param_index=param_index)
