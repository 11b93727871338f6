"""Newton–Krylov with a hookstep trust region (Viswanath 2007/2009, Willis).

The Newton correction ``J s = -F(x)`` is solved approximately in a Krylov
space built by GMRES(m)/Arnoldi: ``J V_k = V_{k+1} H`` with ``H`` the
``(k+1) x k`` Hessenberg matrix. With the SVD ``H = U Σ Wᵀ`` and
``p = β Uᵀ e1`` (``β = |F(x)|``), the *hookstep* of radius ``Δ`` is
``s = V_k W q`` with ``q_i = p_i σ_i / (σ_i² + μ)``; ``μ = 0`` is the GMRES
(least-squares Newton) step, and ``μ`` is raised until ``|q| <= Δ``. The
trust radius follows the rules of ``numerics-notes.md``: residual rose ->
``Δ = |s|/2`` and retry on the same Krylov space; actual/predicted reduction
below 0.75 -> ``Δ = 0.7 |s|``; a good hooked step -> ``Δ`` doubled up to a
cap. The trust region keeps shooting robust far from the solution and near
folds, where the plain Newton step is huge and wrong.

``J v`` comes from the caller (``jvp``) or from one-sided finite
differences of ``F``. Every call of ``F`` is counted (``residual_evals``):
for shooting one residual evaluation is one flow evaluation, the honest
machine-independent cost unit.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from contfil.engine.linalg.krylov import arnoldi
from contfil.engine.linalg.newton import NON_FINITE
from contfil.errors import ConvergenceError, DomainError, NonFiniteError

Array = NDArray[np.float64]

__all__ = ["newton_hookstep", "hookstep_corrector", "hookstep_from_hessenberg", "arnoldi_gmres"]

#: Arnoldi breakdown: the new direction is below this fraction of ``|b|``,
#: i.e. at round-off of an exactly invariant Krylov space.
BREAKDOWN_REL = 1e-14


def arnoldi_gmres(
    matvec: Callable[[Array], Array],
    b: Array,
    m: int,
    rtol: float,
) -> tuple[Array, Array, int]:
    """Arnoldi process for ``J s = b`` (modified Gram–Schmidt, one re-orthogonalisation).

    Returns ``V`` (``n x (k+1)``), ``H`` (``(k+1) x k``) and ``k``, stopping
    as soon as the GMRES residual ``min_y |β e1 - H y|`` drops below
    ``rtol * β`` (or on breakdown, or at ``k = m``).
    """
    beta = float(np.linalg.norm(b))
    if beta == 0.0:
        return np.zeros((b.size, 1)), np.zeros((1, 0)), 0
    e1 = np.zeros(m + 1)
    e1[0] = beta

    def converged(H: Array, k: int, hn: float) -> bool:
        # GMRES residual min_y |beta e1 - H y| of the current space
        y, *_ = np.linalg.lstsq(H[: k + 1, :k], e1[: k + 1], rcond=None)
        res = float(np.linalg.norm(e1[: k + 1] - H[: k + 1, :k] @ y))
        return hn <= BREAKDOWN_REL * beta or res <= rtol * beta

    V, H, k = arnoldi(matvec, b, m, converged, who="arnoldi_gmres")
    return V[:, : k + 1], H[: k + 1, :k], k


def hookstep_from_hessenberg(H: Array, beta: float, delta: float) -> tuple[Array, float, float]:
    """Reduced hookstep ``y`` with ``|y| <= delta`` for ``min |β e1 - H y|``.

    Returns ``(y, mu, predicted_residual_norm)``; ``mu = 0`` when the GMRES
    step already lies inside the trust region.
    """
    k = H.shape[1]
    U, s, Wt = np.linalg.svd(H, full_matrices=False)
    p = beta * U[0, :]  # β Uᵀ e1
    # tiny singular values: the least-squares (pseudo-inverse) step ignores them
    cut = s > 1e-14 * (s[0] if k else 1.0)

    def q_of(mu: float) -> Array:
        q = np.zeros(k)
        q[cut] = p[cut] * s[cut] / (s[cut] ** 2 + mu)
        return q

    q = q_of(0.0)
    mu = 0.0
    if np.linalg.norm(q) > delta:
        # |q(μ)| decreases monotonically in μ: bracket then bisect (in log μ)
        lo, hi = 0.0, max(float(s[0]) ** 2, 1e-300)
        while np.linalg.norm(q_of(hi)) > delta:
            lo, hi = hi, hi * 4.0
        for _ in range(200):
            mid = 0.5 * (lo + hi) if lo == 0.0 else float(np.sqrt(lo * hi))
            if np.linalg.norm(q_of(mid)) > delta:
                lo = mid
            else:
                hi = mid
            if hi - lo <= 1e-10 * hi:
                break
        mu = hi
        q = q_of(mu)
    y = Wt.T @ q
    e1 = np.zeros(H.shape[0])
    e1[0] = beta
    pred = float(np.linalg.norm(e1 - H @ y))
    return y, mu, pred


#: Trust-radius rules (``numerics-notes.md``): an actual/predicted residual
#: reduction below ``POOR_RATIO`` shrinks the radius to ``SHRINK_POOR |s|``;
#: a good hooked step doubles it (``GROW``, up to the cap).
POOR_RATIO = 0.75
SHRINK_POOR = 0.7
GROW = 2.0


def _trust_region_step(
    Fc: Callable[[Array], Array],
    x: Array,
    r: Array,
    rn: float,
    Vk: Array,
    H: Array,
    Delta: float,
    bounds: tuple[float, float],
    max_hooks: int,
) -> tuple[Array, Array, float, float, bool]:
    """One hooked Newton step in the Krylov space ``Vk`` (with Hessenberg
    ``H``): shrink the radius and retry while the residual rises.

    Returns ``(x, r, |r|, Delta, accepted)`` (unchanged point if not accepted).
    """
    delta_min, Dmax = bounds
    for _ in range(max_hooks):
        y, mu, pred = hookstep_from_hessenberg(H, rn, Delta)
        s = Vk @ y
        snorm = float(np.linalg.norm(s))
        x_new = x + s
        try:
            r_new = Fc(x_new)
        except (NonFiniteError, DomainError):
            # the trial point left the domain (e.g. T <= 0): too long a step
            r_new = np.full_like(r, np.inf)
        rn_new = float(np.linalg.norm(r_new)) if np.all(np.isfinite(r_new)) else np.inf
        if rn_new >= rn:
            # residual rose: the linear model is wrong at this distance
            Delta = max(snorm / 2.0, 0.0)
            if Delta < delta_min:
                break
            continue
        ratio = (rn - rn_new) / max(rn - pred, 1e-300)
        if ratio < POOR_RATIO:
            Delta = max(SHRINK_POOR * snorm, delta_min)
        elif mu > 0.0:
            # a good hooked step: the model is trustworthy farther out
            Delta = min(GROW * Delta, Dmax)
        else:
            Delta = min(max(Delta, GROW * snorm), Dmax)
        return x_new, r_new, rn_new, Delta, True
    return x, r, rn, Delta, False


def newton_hookstep(
    F: Callable[[Array], Array],
    x0: Array,
    jvp: Callable[[Array, Array], Array] | None = None,
    tol: float = 1e-10,
    max_iter: int = 50,
    *,
    gmres_m: int | None = None,
    gmres_rtol: float = 1e-3,
    delta: float | None = None,
    delta_max: float | None = None,
    delta_min: float = 1e-12,
    max_hooks: int = 20,
    fd_rel: float = 1e-7,
    raise_on_fail: bool = True,
    norm: str = "2",
    name: str = "newton_hookstep",
) -> tuple[Array, dict[str, Any]]:
    """Solve ``F(x) = 0`` by Newton–Krylov with a hookstep trust region.

    Parameters
    ----------
    F:
        The residual, ``R^n -> R^n``.
    x0:
        Initial guess.
    jvp:
        ``jvp(x, v) -> J(x) v``; one-sided finite differences of ``F`` if None
        (one extra residual evaluation per product).
    tol:
        Convergence when ``|F(x)| <= tol`` (2-norm).
    max_iter:
        Maximum number of Newton (outer) iterations.
    gmres_m:
        Maximum Krylov dimension per Newton step (default ``min(n, 60)``).
    gmres_rtol:
        Forcing term cap: GMRES stops at ``min(gmres_rtol, |F|)`` relative
        residual, so the outer convergence becomes superlinear.
    delta, delta_max, delta_min:
        Initial, maximal and minimal trust radius (defaults ``1 + |x0|``,
        ``1e3 (1 + |x0|)``, ``1e-12``).
    max_hooks:
        Retries with a shrunken trust radius per Newton step.
    raise_on_fail:
        Raise :class:`ConvergenceError` (with the last residual) on failure;
        otherwise return with ``info["converged"] = False``.
    norm:
        ``"2"`` or ``"inf"``: the norm of ``F`` compared with ``tol`` (the
        trust-region logic always uses the 2-norm).

    Returns
    -------
    x, info:
        ``info`` holds ``converged``, ``iterations``, ``residual`` (final
        ``|F|``), ``residual_evals``, ``jvp_evals``, ``krylov_dims``,
        ``history`` (``|F|`` per iteration) and ``trust_radius``.
    """
    x = np.array(x0, dtype=float, copy=True)
    n = x.size
    m = int(gmres_m) if gmres_m is not None else min(n, 60)
    m = max(1, min(m, n))
    counts = {"F": 0, "jvp": 0}

    def Fc(z: Array) -> Array:
        counts["F"] += 1
        r = np.asarray(F(z), dtype=float)
        if r.shape != (n,):
            raise ValueError(f"{name}: residual has shape {r.shape}, expected ({n},)")
        return r

    r = Fc(x)
    if not np.all(np.isfinite(r)):
        raise NonFiniteError(f"{name}: residual at the initial guess is not finite")
    rn = float(np.linalg.norm(r))
    scale = 1.0 + float(np.linalg.norm(x))
    Delta = float(delta) if delta is not None else scale
    Dmax = float(delta_max) if delta_max is not None else 1e3 * scale
    if norm not in ("2", "inf"):
        raise ValueError(f"{name}: norm must be '2' or 'inf', got {norm!r}")

    def tnorm(z: Array) -> float:
        return float(np.max(np.abs(z))) if norm == "inf" else float(np.linalg.norm(z))

    history = [rn]
    kdims: list[int] = []
    it = 0
    status = "max_iter"
    while tnorm(r) > tol:
        if it >= max_iter:
            break
        it += 1
        x_base, r_base = x, r

        def matvec(v: Array, x_base: Array = x_base, r_base: Array = r_base) -> Array:
            counts["jvp"] += 1
            if jvp is not None:
                return np.asarray(jvp(x_base, v), dtype=float)
            nv = float(np.linalg.norm(v))
            eps = fd_rel * (1.0 + float(np.linalg.norm(x_base))) / nv
            return (Fc(x_base + eps * v) - r_base) / eps

        eta = min(gmres_rtol, max(rn, 1e-12))
        V, H, k = arnoldi_gmres(matvec, -r, m, eta)
        kdims.append(k)
        if k == 0:
            status = "zero_krylov"
            break
        x, r, rn, Delta, accepted = _trust_region_step(
            Fc, x, r, rn, V[:, :k], H, Delta, (delta_min, Dmax), max_hooks)
        history.append(rn)
        if not accepted:
            status = "trust_region_collapsed"
            break
    converged = bool(tnorm(r) <= tol)
    if converged:
        status = "converged"
    info: dict[str, Any] = {
        "converged": converged,
        "status": status,
        "iterations": it,
        "residual": tnorm(r),
        "residual_evals": counts["F"],
        "jvp_evals": counts["jvp"],
        "krylov_dims": kdims,
        "history": history,
        "trust_radius": Delta,
    }
    if not converged and raise_on_fail:
        raise ConvergenceError(
            f"{name}: no convergence after {it} Newton iterations ({status}); "
            f"last residual |F| = {rn:.3e} (tol {tol:.1e}), trust radius {Delta:.3e}, "
            f"{counts['F']} residual evaluations"
        )
    return x, info


def hookstep_corrector(**options: Any) -> Callable[..., tuple[Array, Any]]:
    """A corrector for the continuation driver, backed by :func:`newton_hookstep`.

    Returns ``corrector(F, jvp, X0, tol, max_iter) -> (X, NewtonInfo)`` with
    the convention of :mod:`contfil.engine.linalg.newton`: the augmented system
    (``X = (x, p)``) is solved to ``max|F| <= tol``; plain non-convergence is
    reported (``converged=False`` with the last residual), not raised, so the
    driver can cut its step. ``jvp`` may be None (finite differences).
    ``options`` go to :func:`newton_hookstep`; the counts of residual
    evaluations are kept in ``corrector.counts``.
    """
    from contfil.engine.linalg.newton import NewtonInfo

    counts = {"calls": 0, "residual_evals": 0, "jvp_evals": 0}

    def corrector(
        F: Callable[[Array], Array],
        jvp: Callable[[Array, Array], Array] | None,
        X0: Array,
        tol: float,
        max_iter: int,
    ) -> tuple[Array, Any]:
        opts = {"norm": "inf", **options, "raise_on_fail": False}
        try:
            X, info = newton_hookstep(F, X0, jvp=jvp, tol=tol, max_iter=max_iter, **opts)
        except NonFiniteError:
            return np.array(X0, dtype=float), NewtonInfo(
                converged=False, iterations=0, residual=float("inf"), reason=NON_FINITE
            )
        counts["calls"] += 1
        counts["residual_evals"] += info["residual_evals"]
        counts["jvp_evals"] += info["jvp_evals"]
        hist = [float(h) for h in info["history"]]
        return X, NewtonInfo(
            converged=info["converged"],
            iterations=info["iterations"],
            residual=info["residual"],
            history=hist,
            reason="" if info["converged"] else info["status"],
            linear_iterations=int(sum(info["krylov_dims"])),
        )

    corrector.counts = counts  # type: ignore[attr-defined]
    return corrector
