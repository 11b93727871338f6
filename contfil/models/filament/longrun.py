"""Long-time simulation of the filament with bounded memory.

The BDF2 integrator (:class:`~contfil.models.filament.integrators.bdf2.BDF2Stepper`)
keeps its two-step history between calls, so stepping it in chunks gives the
same states as one long run (:func:`~contfil.models.filament.integrators.bdf2.trajectory`
with the same ``dt``, to round-off: the tests check this). A :class:`LongRun`
advances ``sample_every`` steps at a time and yields one :class:`Sample`
(time, state, tip) per chunk; nothing is kept, so 10^6 steps cost no more
memory than ten.

The samples feed the generic tools of :mod:`contfil.analysis`:

- :func:`classify_run` streams states into
  :func:`~contfil.analysis.classify.classify_samples` (tip position as the
  observable, the per-segment ``U_1^2 + U_2^2`` as the rotation invariant:
  the paper's whirling test, Appendix "Use in the Bisection Method") and
  returns the classification with the data of a graph "state" node
  (:meth:`contfil.graph.branch_graph.BranchGraph.add_state`);
- :func:`step_map` is a *pure* map ``u -> phi_{m dt}(u)`` (a fresh BDF2 run
  of ``m`` steps, backward Euler first), as
  :func:`~contfil.analysis.lyapunov.largest_lyapunov` (two-trajectory finite
  differences) and :func:`~contfil.analysis.bisection.edge_track` need: both
  evolve several states through the same map, which a stateful stepper
  cannot do.

:func:`classify_run` measures the largest Lyapunov exponent along the
classified trajectory itself (decisions 39): the classified run is the
reference of :class:`~contfil.analysis.lyapunov.LockstepLyapunov`, a
companion BDF2 run is stepped in lockstep and put back next to it after every
map. The BDF2 map acts on the pair ``(u_k, u_{k-1})`` (the step uses the
previous state and increment), so that pair is the space in which the
companion is perturbed and renormalised (:class:`BDF2Lockstep`); a restart of
the companion by backward Euler would differ from the reference's step by
the method's local error, far above the companion's distance.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from contfil.analysis.classify import AttractorClass, classify_samples, redecide
from contfil.analysis.lyapunov import LockstepLyapunov
from contfil.errors import NonFiniteError, SpecError

from .integrators.bdf2 import BDF2Stepper, flow
from .kernels.geometry import frames_from_state, positions, tangents
from .physics import embed_planar

Array = NDArray[np.float64]

__all__ = [
    "Sample",
    "LongRun",
    "step_map",
    "BDF2Lockstep",
    "tip_position",
    "rotation_invariant",
    "classify_run",
    "state_node_data",
]


@dataclass(frozen=True)
class Sample:
    """One sample of a long run: time, step index, model state and free end."""

    t: float
    k: int
    u: Array
    tip: Array


def _full(model: Any, u: Array) -> Array:
    return embed_planar(u) if model.planar else np.asarray(u, dtype=float)


def tip_position(model: Any, u: Array) -> Array:
    """Free end ``X_N + dL/2 t_N`` (3,) of state ``u``."""
    t = tangents(frames_from_state(_full(model, u)))
    X = positions(t, model.dL)
    return X[-1] + 0.5 * model.dL * t[-1]


def rotation_invariant(model: Any, u: Array) -> Array:
    """``U_1^2 + U_2^2`` per segment (N-1,): constant in time on whirling.

    Whirling is a rigid rotation about e3, which turns each ``U_n`` about e3
    (the paper's Appendix "Use in the Bisection Method", eq. biseq2).
    """
    U = _full(model, u).reshape(-1, 3)
    return U[:, 0] ** 2 + U[:, 1] ** 2


class LongRun:
    """Streaming BDF2 run of a filament model (bounded memory).

    Parameters
    ----------
    model:
        A :class:`~contfil.models.filament.model.FilamentModel`.
    u0:
        Initial state (model layout).
    p:
        Parameter vector (actuation strength).
    dt:
        BDF2 time step.
    sample_every:
        Steps between samples.
    stepper_kw:
        Passed to :class:`BDF2Stepper` (``tol``, ``jacobian``, ...).

    Examples
    --------
    >>> run = LongRun(model, u0, p, dt=T / 400, sample_every=10)   # doctest: +SKIP
    >>> for s in run.samples(10_000): ...                          # doctest: +SKIP
    """

    def __init__(self, model: Any, u0: Array, p: Array | None, dt: float,
                 sample_every: int = 1, **stepper_kw: Any) -> None:
        if int(sample_every) < 1:
            raise SpecError(f"LongRun: sample_every must be >= 1, got {sample_every!r}")
        if not (np.isfinite(dt) and dt > 0):
            raise SpecError(f"LongRun: dt must be positive and finite, got {dt!r}")
        self.model = model
        self.p = None if p is None else np.asarray(p, dtype=float)
        self.sample_every = int(sample_every)
        self.stepper = BDF2Stepper(model, float(dt), p=self.p, **stepper_kw)
        self.stepper.reset(np.asarray(u0, dtype=float))
        self.dt = self.stepper.dt
        self.broyden_iterations = 0

    @property
    def k(self) -> int:
        """Steps taken so far."""
        return self.stepper.k

    @property
    def t(self) -> float:
        """Current time."""
        return self.stepper.time

    @property
    def state(self) -> Array:
        """Current state (model layout)."""
        return self.stepper.state

    def advance(self, n_steps: int) -> Array:
        """Advance ``n_steps`` BDF2 steps (a transient, say) and return the state."""
        if n_steps < 0:
            raise SpecError(f"LongRun.advance: n_steps must be >= 0, got {n_steps}")
        u = self.stepper.step(int(n_steps))
        if n_steps:
            self.broyden_iterations += int(np.sum(self.stepper.last_diagnostics.iterations))
        if not np.all(np.isfinite(u)):
            raise NonFiniteError(f"LongRun: state not finite at t = {self.t:.6g}")
        return u

    def sample(self) -> Sample:
        """Advance ``sample_every`` steps and return the sample there."""
        u = self.advance(self.sample_every)
        q = self.stepper.frames
        t = tangents(q)
        tip = positions(t, self.model.dL)[-1] + 0.5 * self.model.dL * t[-1]
        return Sample(self.t, self.k, u, tip)

    def samples(self, n_samples: int) -> Iterator[Sample]:
        """Yield ``n_samples`` samples, ``sample_every`` steps apart (nothing is kept)."""
        for _ in range(int(n_samples)):
            yield self.sample()

    def states(self, n_samples: int) -> Iterator[Array]:
        """Yield only the states of :meth:`samples` (for ``classify_samples``)."""
        for s in self.samples(n_samples):
            yield s.u


class BDF2Lockstep:
    """A :class:`LongRun` as a :class:`~contfil.analysis.lyapunov.LockstepSystem`.

    The map state (:meth:`history`) is ``(u_k, u_{k-1})`` in model layout: the
    BDF2 step from ``k`` uses the frames and positions at ``k`` and ``k-1``
    and the increment ``log(q^k q^{k-1 *})``, all functions of that pair.
    :meth:`follow` rebuilds them from a pair and takes the loads (the
    Broyden predictor), the carried inverse Jacobian, the step index and the
    time from the reference's stepper, so a companion placed at the
    reference's own pair takes the reference's next steps to round-off
    (``test_lockstep_companion_at_the_reference_follows_it``).

    ``u_prev`` is the state before the run's last step (``u`` itself before
    the first: the first step is backward Euler and ignores it).
    """

    def __init__(self, run: LongRun, u_prev: Array | None = None) -> None:
        self.run = run
        self._prev = np.array(run.state if u_prev is None else u_prev, dtype=float)

    def advance(self, n: int) -> None:
        """Take ``n >= 1`` steps, keeping the state before the last."""
        if n < 1:
            raise SpecError(f"BDF2Lockstep.advance: n must be >= 1, got {n}")
        if n > 1:
            self.run.advance(n - 1)
        self._prev = self.run.state
        self.run.advance(1)

    def history(self) -> Array:
        """``(u_k, u_{k-1})`` concatenated."""
        return np.concatenate([self.run.state, self._prev])

    def follow(self, reference: Any, h: Array) -> None:
        """Be at the pair ``h``, with the reference stepper's loads, Jacobian and step."""
        n = h.size // 2
        up = np.asarray(h[n:], dtype=float)
        self.run.stepper.set_history(np.asarray(h[:n], dtype=float), up,
                                     reference.run.stepper)
        self._prev = up.copy()


def step_map(model: Any, p: Array | None, dt: float, steps: int = 1,
             **stepper_kw: Any) -> Callable[[Array], Array]:
    """Pure map ``u -> phi_{steps dt}(u)``: a fresh BDF2 run of ``steps`` steps.

    Each call restarts the integrator (first step backward Euler), so the map
    depends on ``u`` alone, as edge tracking and two-trajectory Lyapunov
    estimates need. Its local error is O(dt^2) per call, against O(dt^3) of a
    continued BDF2 step; use ``steps`` of tens to keep the restarts rare.
    """
    if int(steps) < 1:
        raise SpecError(f"step_map: steps must be >= 1, got {steps!r}")
    T = float(dt) * int(steps)
    pp = None if p is None else np.asarray(p, dtype=float)

    def _step(u: Array) -> Array:
        return flow(model, np.asarray(u, dtype=float), pp, T, steps=int(steps), **stepper_kw)

    return _step


def _summary(res: AttractorClass) -> dict[str, Any]:
    """JSON-safe evidence of a classification (numbers and short lists only)."""
    ev: dict[str, Any] = {"label": res.label, "reasons": list(res.reasons),
                          "n_samples": int(res.n_steps), "sample_dt": float(res.dt),
                          "section_crossings": int(res.section.n_crossings),
                          "section_distinct": int(res.section.n_distinct),
                          "mean_return_time": float(res.section.mean_return_time)}
    if res.spectrum is not None:
        sp = res.spectrum
        ev.update(bases=[float(b) for b in sp.bases], peaks=[float(f) for f in sp.peaks[:12]],
                  discrete_fraction=float(sp.discrete_fraction),
                  frequency_resolution=float(sp.frequencies[1] - sp.frequencies[0])
                  if sp.frequencies.size > 1 else float("nan"))
    if res.invariant_mean is not None and res.invariant_std is not None:
        scale = float(np.max(np.abs(res.invariant_mean))) or 1.0
        ev["invariant_rel_std"] = float(np.max(res.invariant_std) / scale)
    if res.lyapunov is not None:
        ev.update(lyapunov=float(res.lyapunov.exponent), lyapunov_error=float(res.lyapunov.error),
                  lyapunov_block_means=[float(b) for b in res.lyapunov.block_means])
    return ev


def state_node_data(res: AttractorClass, model: Any, p: Array | None,
                    extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """The arguments of :meth:`BranchGraph.add_state` for a classification.

    ``{"kind", "param", "p", "evidence"}``; ``evidence`` is JSON-safe and
    holds the label's reasons, the spectral bases and peaks, the section
    counts and the Lyapunov exponent when computed, plus ``extra``.
    """
    names = tuple(getattr(model, "param_names", ()))
    pv = float(np.asarray(p, dtype=float).ravel()[0]) if p is not None and len(names) else 0.0
    ev = _summary(res)
    if extra:
        ev.update(extra)
    return {"kind": res.label, "param": names[0] if names else "", "p": pv, "evidence": ev}


def classify_run(
    model: Any,
    u0: Array,
    p: Array | None,
    dt: float,
    n_samples: int,
    *,
    sample_every: int = 1,
    transient_steps: int = 0,
    lyapunov_samples: int = 0,
    lyapunov_map_steps: int | None = None,
    stepper_kw: dict[str, Any] | None = None,
    **classify_kw: Any,
) -> tuple[AttractorClass, dict[str, Any]]:
    """Run the filament, classify its attractor and return ``(result, node_data)``.

    Parameters
    ----------
    model, u0, p, dt:
        Model, initial state, parameters and BDF2 step.
    n_samples:
        Samples classified after the transient, ``sample_every`` steps apart.
    transient_steps:
        Steps discarded first.
    lyapunov_samples:
        If > 0, the largest Lyapunov exponent along the classified trajectory
        (:class:`~contfil.analysis.lyapunov.LockstepLyapunov`, a companion
        run renormalised every map of ``lyapunov_map_steps`` steps, default
        ``sample_every``), averaged over the *last* ``min(lyapunov_samples,
        W)`` maps of the classified window of ``W = n_samples sample_every //
        lyapunov_map_steps`` maps; the window's earlier maps align the
        direction. So ``lyapunov_samples >= W`` (the usual choice) gives the
        exponent over the whole classified window, the same trajectory and
        the same time span as the section and spectrum. The evidence records
        ``lyapunov_maps`` and ``lyapunov_skip_maps``.
    classify_kw:
        Passed to :func:`~contfil.analysis.classify.classify_samples`
        (defaults here: tip position as observable, :func:`rotation_invariant`).

    Returns
    -------
    tuple
        The :class:`AttractorClass` and :func:`state_node_data` of it.
    """
    skw = dict(stepper_kw or {})
    run = LongRun(model, u0, p, dt, sample_every, **skw)
    nt = int(transient_steps)
    if nt > 0:
        run.advance(nt - 1)
    u_prev = run.state
    run.advance(min(nt, 1))
    extra: dict[str, Any] = {"dt": run.dt, "sample_every": run.sample_every,
                             "transient_steps": nt}
    classify_kw.setdefault("observable", lambda u: tip_position(model, u))
    classify_kw.setdefault("invariant", lambda u: rotation_invariant(model, u))
    if lyapunov_samples <= 0:
        res = classify_samples(run.states(n_samples), run.dt * run.sample_every, n_samples,
                               **classify_kw)
        extra["t_end"] = run.t
        return res, state_node_data(res, model, p, extra)
    m = int(lyapunov_map_steps or sample_every)
    window = int(n_samples) * run.sample_every // m
    n_maps = min(int(lyapunov_samples), window)
    ref = BDF2Lockstep(run, u_prev)
    comp = BDF2Lockstep(LongRun(model, run.state, p, dt, 1, **skw))
    lock = LockstepLyapunov(ref, comp, m, n_maps, run.dt, skip_maps=window - n_maps,
                            n_blocks=10)

    def states() -> Iterator[Array]:
        for _ in range(int(n_samples)):
            lock.advance(run.sample_every)
            yield run.state

    kw = {k: v for k, v in classify_kw.items() if k not in ("lyapunov",)}
    res = classify_samples(states(), run.dt * run.sample_every, n_samples, **kw)
    # the exponent of the same window, weighed in as classify_samples would
    # (the window's last maps are complete: n_samples sample_every >= window m)
    lyap = lock.result()
    res = redecide(res, lyap, **{k: v for k, v in kw.items() if k in (
        "fp_tol", "rw_tol", "section_tol", "max_period", "discrete_power", "lyap_tol")})
    extra.update(lyapunov_map_steps=m, lyapunov_maps=n_maps, lyapunov_skip_maps=window - n_maps,
                 lyapunov_method="lockstep", t_end=run.t)
    return res, state_node_data(res, model, p, extra)
