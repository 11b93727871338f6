"""The interface every continuable problem implements.

A *problem* is a parametrised nonlinear system ``G(x, p) = 0`` with
``x`` in R^n and a scalar continuation parameter ``p``. Equilibria
(``x = u``), rotating waves (``x = (u, omega)``) and periodic orbits by
shooting (``x = (u, T[, drift])``) are all problems; the continuation
driver is written once, against this interface, and never looks inside.

Finite-difference defaults are provided for the derivatives; subclasses
override them when they can do better.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


@dataclass
class Stability:
    """Spectral data of a solution.

    ``values`` are eigenvalues (``kind == "eigenvalues"``; unstable when
    Re > 0) or Floquet multipliers (``kind == "multipliers"``; unstable when
    |mu| > 1), sorted leading first. ``trivial`` flags the ones forced by
    time shift or continuous symmetry. ``vectors`` (optional, columns) are the
    matching eigenvectors, needed for branch switching.
    """

    values: NDArray[np.complex128]
    kind: str = "eigenvalues"
    trivial: NDArray[np.bool_] | None = None
    vectors: NDArray[np.complex128] | None = None
    residual: float = float("nan")
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def n_unstable(self) -> int:
        mask = np.ones(len(self.values), dtype=bool) if self.trivial is None else ~self.trivial
        v = self.values[mask]
        if self.kind == "multipliers":
            return int(np.sum(np.abs(v) > 1.0))
        return int(np.sum(v.real > 0.0))


def fd_step(x: Array, v: Array, rel: float = 1e-7) -> float:
    """Finite-difference increment so that ``eps*|v|`` is ~``rel*(1+|x|)``."""
    nv = float(np.linalg.norm(v))
    if nv == 0.0:
        return 0.0
    return rel * (1.0 + float(np.linalg.norm(x))) / nv


#: Relative step of the central-difference Jacobian of :class:`Problem`:
#: about the cube root of machine epsilon (1e-16^(1/3) ~ 5e-6), the optimum
#: of a central difference, rounded.
FD_CENTRAL_REL = 1e-6


def fd_jacobian(f: Callable[[Array], Array], x: Array, rel: float = FD_CENTRAL_REL) -> Array:
    """Dense Jacobian of ``f`` at ``x`` by central differences.

    Column ``j`` uses the step ``h_j = rel (1 + |x_j|)`` (error ``O(h^2)``
    plus round-off ``O(eps / h)``). The one finite-difference Jacobian of
    the engine: problems call it with their own residual and ``fd_rel``.
    """
    n = x.size
    J = np.empty((n, n))
    h = rel * (1.0 + np.abs(x))
    for j in range(n):
        e = np.zeros(n)
        e[j] = h[j]
        J[:, j] = (f(x + e) - f(x - e)) / (2.0 * h[j])
    return J


class Problem(ABC):
    """``G(x, p) = 0`` to be continued in ``p``.

    Attributes
    ----------
    n:
        Number of unknowns in ``x`` (equal to the number of equations).
    kind:
        Branch kind produced (see :mod:`contfil.engine.branch`).
    dense:
        True when a dense Jacobian is affordable (small systems); the
        continuation then uses dense linear algebra, otherwise Krylov.

    Optional hooks (declared here with defaults; the driver calls them
    unconditionally): ``param``, ``subspace``, ``rhs_evals`` /
    ``flow_evals`` (cost counters), ``fast_iter`` and ``jacobian_effort`` (step
    growth),
    :meth:`params_at`, :meth:`params_of`, :meth:`observables`, :meth:`default_events`,
    :meth:`sparse_jacobian`, :meth:`preconditioner`,
    :meth:`accept`, :meth:`restart_data` / :meth:`restore` (what a resumed
    run needs besides ``(x, p)``, e.g. a phase reference), :meth:`refine` /
    :meth:`onto_refined` (a finer discretisation of the same problem, for
    error estimates from two resolutions).
    """

    n: int
    kind: str
    dense: bool = True
    #: Name of the continuation parameter.
    param: str = "p"
    #: Invariant subspace the problem is solved in (``None``: the full space).
    subspace: Any = None
    #: Cumulative right-hand-side evaluations (``None``: not counted).
    rhs_evals: int | None = None
    #: Cumulative flow evaluations, for time-steppers (``None``: not counted).
    flow_evals: int | None = None
    #: Corrector iterations that still count as a fast step for this problem
    #: (``None``: the run's ``fast_iter`` alone decides when ``ds`` grows).
    fast_iter: int | None = None
    #: Cumulative corrector effort in Newton-iteration units, for problems
    #: whose iterations differ in kind (``None``: every iteration counts 1;
    #: the step control then reads the iteration count).
    jacobian_effort: float | None = None
    #: Order of the discretisation error of the reported quantities (period,
    #: multipliers), when known: the estimate from two resolutions (factor 2)
    #: is then ``1 - 2^-order`` of the coarse error (``None``: unknown).
    discretisation_order: int | None = None

    @abstractmethod
    def residual(self, x: Array, p: float) -> Array:
        """``G(x, p)``."""

    def jacobian(self, x: Array, p: float) -> Array:
        """Dense ``G_x`` by central differences (override when known)."""
        return fd_jacobian(lambda y: self.residual(y, p), x)

    def jvp(self, x: Array, p: float, v: Array, g0: Array | None = None) -> Array:
        """``G_x v`` by a one-sided finite difference (``g0 = G(x, p)`` if known)."""
        eps = fd_step(x, v)
        if eps == 0.0:
            return np.zeros_like(x)
        if g0 is None:
            g0 = self.residual(x, p)
        return (self.residual(x + eps * v, p) - g0) / eps

    def dp(self, x: Array, p: float) -> Array:
        """``G_p`` by central differences."""
        h = FD_CENTRAL_REL * (1.0 + abs(p))
        return (self.residual(x, p + h) - self.residual(x, p - h)) / (2 * h)

    def accept(self, x: Array, p: float) -> None:
        """Hook called when a point is accepted (e.g. to move phase-condition
        references). Default: nothing."""
        return None

    @abstractmethod
    def stability(self, x: Array, p: float, vectors: bool = False) -> Stability:
        """Eigenvalues or Floquet multipliers at a solution (with eigenvectors
        when ``vectors``; a problem may return them anyway)."""

    @abstractmethod
    def state(self, x: Array) -> Array:
        """The model state ``u`` contained in ``x``."""

    def extra(self, x: Array) -> dict[str, float]:
        """Kind-specific unknowns in ``x`` (period, omega, drift)."""
        return {}

    # ------------------------------------------------------- loop detection
    def loop_images(self, reflections: bool = True) -> dict[str, Array]:
        """The state maps under which a solution counts as the same one for
        loop detection: ``"identity"`` (an empty matrix) and, with
        ``reflections``, the model's declared reflections
        (``model.symmetries.reflections``, matrices on the full state)."""
        out: dict[str, Array] = {"identity": np.eye(0)}
        if not reflections:
            return out
        sym = getattr(getattr(self, "model", None), "symmetries", None)
        for name, R in (getattr(sym, "reflections", None) or {}).items():
            out[str(name)] = np.asarray(R, dtype=float)
        return out

    def loop_key(self, x: Array) -> Array:
        """Cheap scalars that a return to an earlier solution (or its image
        under :meth:`loop_images`) must reproduce: here the state's norm
        (reflections are orthogonal) and the kind's unknowns other than a
        drift (a reflection reverses a drift)."""
        ex = [float(v) for k, v in self.extra(x).items() if k != "drift"]
        return np.array([float(np.linalg.norm(self.state(x))), *ex])

    def loop_distance(self, x: Array, p: float, x_ref: Array,
                      reflections: bool = True) -> tuple[float, str]:
        """Relative distance of the solution ``x`` from ``x_ref`` or its
        nearest image (:meth:`loop_images`) and that image's name. Default:
        the states compared as they are, which for a periodic orbit depends
        on the phase origin (a return may then go unseen, never be seen
        falsely); :class:`~contfil.engine.problems.shooting.PeriodicOrbitProblem`
        minimises over the phase."""
        u, v = np.asarray(self.state(x), dtype=float), np.asarray(self.state(x_ref), dtype=float)
        scale = max(float(np.linalg.norm(u)), float(np.linalg.norm(v)), 1e-300)
        best = (float("inf"), "identity")
        for name, R in self.loop_images(reflections).items():
            w = v if R.size == 0 else R @ v
            d = float(np.linalg.norm(u - w)) / scale
            if d < best[0]:
                best = (d, name)
        return best

    # ------------------------------------------------------- optional hooks
    def params_at(self, p: float) -> Array:
        """The model's full parameter vector at ``p`` (default: ``[p]``)."""
        return np.array([p])

    def params_of(self, x: Array, p: float) -> Array:
        """The full parameter vector of the solution ``(x, p)`` (``Point.params``;
        default: :meth:`params_at`). Problems whose unknowns hold a parameter
        (a two-parameter curve) override it."""
        return self.params_at(p)

    def observables(self, x: Array, p: float) -> dict[str, Any] | None:
        """Scalar observables stored with each point (``None``: none)."""
        return None

    def default_events(self) -> list[Any] | None:
        """The problem's own default events (``None``: the standard ones of
        its ``kind``)."""
        return None

    def sparse_jacobian(self, x: Array, p: float) -> Any | None:
        """``G_x`` as a scipy sparse matrix, when cheap (``None``: not available)."""
        return None

    def preconditioner(self, x: Array, p: float) -> Callable[[Array], Array] | None:
        """An approximate ``G_x^{-1}`` for matrix-free solves (``None``: none)."""
        return None

    def restart_data(self) -> dict[str, Array]:
        """State a resumed run needs besides ``(x, p)`` and the tangent, as
        plain arrays (e.g. the phase-condition reference after the last
        :meth:`accept`). Default: nothing."""
        return {}

    def restore(self, data: dict[str, Array]) -> None:
        """Restore what :meth:`restart_data` returned. Default: nothing."""
        return None

    def rephase(self, x: Array, p: float, shift: float) -> tuple[Array, NDArray[np.bool_]] | None:
        """The same solution with its phase origin moved along it by
        ``shift`` (a fraction of its period), the problem's phase references
        moved there, and the mask of the unknowns the move leaves unchanged
        (the period, a drift: what orients the tangent there); ``None`` when
        a solution has no phase origin to move (the default: equilibria).

        The driver calls it when a step fails at ``ds_min`` (docs/decisions.md
        42): the state coordinates of a model may have a cut (an angle or a
        rotation vector returned in ``(-pi, pi]``) that a branch's phase
        origin runs into, while the rest of the orbit is clear of it."""
        return None

    def refine(self, factor: int = 2) -> Problem | None:
        """The same problem on a discretisation ``factor`` times finer (time
        steps, mesh intervals), with the same phase references, or ``None``
        when the problem has no discretisation to refine (the default; an
        equilibrium has none). Used for error estimates from two resolutions
        (:mod:`contfil.engine.continuation.error_estimates`)."""
        return None

    def onto_refined(self, x: Array, fine: Problem) -> Array:
        """The unknowns ``x`` of this problem carried onto ``fine`` (a problem
        returned by :meth:`refine`): a starting guess for a solve there.
        Default: ``x`` itself (same unknowns at both resolutions)."""
        return np.array(x, dtype=float, copy=True)


def resolve_params(model: Any, params: Any, who: str) -> Array:
    """The full parameter vector of ``model`` (its defaults if ``params`` is None),
    checked against ``model.param_names``; ``who`` names the caller in the error."""
    from contfil.errors import SpecError

    base = model.default_params() if params is None else params
    base = np.array(base, dtype=float)
    if base.shape != (len(model.param_names),):
        raise SpecError(
            f"{who}: params has shape {base.shape}; model {model.name!r} "
            f"has {len(model.param_names)} parameters {list(model.param_names)}"
        )
    return base
