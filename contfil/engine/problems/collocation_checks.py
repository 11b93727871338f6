"""Stability and accuracy checks of collocation orbits.

Functions of a :class:`~contfil.engine.problems.collocation.CollocationProblem`
(passed as ``self``): all Floquet multipliers from the condensed transfer
blocks, the trivial-multiplier check (the time-shift mode carried interval by
interval) and the independent DOP853 check of an orbit as a pseudo-orbit.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from contfil.engine.linalg.collocation_floquet import pencil_multipliers, trivial_defect
from contfil.engine.linalg.floquet import flag_trivial
from contfil.engine.problems.base import Stability
from contfil.errors import ConvergenceError

Array = NDArray[np.float64]

__all__ = ["orbit_stability", "check_orbit", "verify_orbit"]


def orbit_stability(self: Any, x: Array, p: float, vectors: bool = True) -> Stability:
    """All Floquet multipliers of the orbit ``x`` of collocation problem ``self``.

    The multipliers are the eigenvalues of the reduced periodic pencil
    (:func:`~contfil.engine.linalg.collocation_floquet.pencil_multipliers`);
    ``info`` holds ``trivial_distance`` (``|μ_trivial - 1|``),
    ``trivial_defect`` (the trivial-multiplier check) and ``mesh_error``.
    """
    blocks = self.full_transfer_blocks(x, p)
    # The time-shift eigenvector f(u) is told apart by projection where the
    # orbit is fastest: at a slow phase origin (near a saddle) f(u_0) lines
    # up with the saddle's eigenvectors. The multipliers are the same at
    # every mesh point; the eigenvectors returned are those at u_0.
    U = self.split(x)[0]
    fU = self.vf.f(U, self.params_at(p))
    j = int(np.argmax(np.linalg.norm(fU, axis=1)))
    mu_j, V_j = pencil_multipliers(np.concatenate([blocks[j:], blocks[:j]]))
    # f(u_j) is at hand (trivial_directions evaluates it again, and adds the
    # symmetry directions of an orbit solved in a subspace)
    dirs = [fU[j]] if self._embed is None else self.trivial_directions(x, p, j)
    flags, tinfo = flag_trivial(mu_j, V_j, dirs)
    if vectors and j > 0:
        mu, V = pencil_multipliers(blocks)
        trivial = np.zeros(mu.size, dtype=bool)
        for k in np.flatnonzero(flags):
            free = np.flatnonzero(~trivial)
            trivial[free[int(np.argmin(np.abs(mu[free] - mu_j[k])))]] = True
        tinfo["distance_from_one"] = float(np.max(np.abs(mu[trivial] - 1.0))) \
            if trivial.any() else float("nan")
    else:
        mu, V, trivial = mu_j, (V_j if vectors else None), flags
    amu = np.abs(mu)
    # by modulus, pairs by the sign of Im (rounding only where it cannot overflow)
    order = np.lexsort((-mu.imag, -np.where(amu < 1e200, np.round(np.minimum(amu, 1e200),
                                                                      12), amu)))
    mu, trivial = mu[order], trivial[order]
    V = None if V is None else V[:, order]
    T = float(x[-1])
    _, err = self.monitor(x, p)
    # the time-shift mode interval by interval: Φ'_j f(u_j) = f(u_{j+1})
    # for the flow; its defect is linear in the discretisation error, also
    # at a fold, where |μ_trivial - 1| grows like its square root (Jordan
    # pair), and it needs no product of blocks (no overflow)
    defect = trivial_defect(self.transfer_blocks(x, p), np.ascontiguousarray(fU))
    info: dict[str, Any] = {"trivial_info": tinfo, "method": "collocation",
                            "trivial_distance": float(tinfo.get("distance_from_one", np.nan)),
                            "trivial_defect": defect,
                            "mesh_error": float(np.max(err))}
    with np.errstate(all="ignore"):
        info["exponents"] = np.log(mu.astype(complex)) / T
    return Stability(values=mu, kind="multipliers", trivial=trivial, vectors=V,
                     residual=float("nan"), info=info)

def check_orbit(self: Any, x: Array, p: float, st: Stability) -> None:
    """Reject an orbit that fails the trivial-multiplier check or (with
    ``verify``) the independent-integration check, naming it and the remedy."""
    info = st.info
    where = f"{self.param}={p:.10g}, T={float(x[-1]):.6g}"
    hint = (f"increase ntst (now {self.ntst})" + ("" if self.adapt else " or set adapt=True")
            + " or take smaller steps (ds_max)")
    dist = info["trivial_defect"]
    if not (dist <= self.trivial_tol):
        raise ConvergenceError(
            f"collocation: orbit at {where} fails the trivial-multiplier check: the "
            f"time-shift mode f(u) is not carried into itself, max_j |Φ'_j f(u_j) - "
            f"f(u_j+1)| / max|f| = {dist:.3g} > trivial_tol = {self.trivial_tol:g} "
            f"(|μ_trivial - 1| = {info['trivial_distance']:.3g}); the mesh does not "
            f"resolve the orbit: {hint}")
    if self.verify > 0 and self.stats["stability_calls"] % self.verify == 0:
        info.update(verify_orbit(self, x, p))
        scale = 1.0 + float(np.max(np.abs(x[:-1])))
        if not (info["interval_defect"] <= self.verify_tol * scale):
            raise ConvergenceError(
                f"collocation: orbit at {where} fails the independent-integration check: "
                f"pseudo-orbit defect {info['interval_defect']:.3g} > "
                f"verify_tol = {self.verify_tol:g} (DOP853); {hint}")

def verify_orbit(self: Any, x: Array, p: float, rtol: float = 1e-11) -> dict[str, float]:
    """Independent DOP853 checks of an orbit (scipy, tight tolerances).

    ``interval_defect``: the orbit is cut into pieces of physical length
    at most ``1/|∂f/∂u|`` (so an integration error grows by at most a
    factor ``e`` over a piece) and each piece is integrated from the
    collocation polynomial's value at its start, all pieces at once as
    one vectorised system: ``max_k |φ_{Δt_k}(u(t_k)) - u(t_{k+1})|``. A
    pseudo-orbit with small defects lies near a true orbit (shadowing),
    also where the period is long and the multipliers huge.
    ``periodicity_residual``: ``|φ_T(u_0) - u_0|`` over the whole period,
    meaningful only while the multipliers are moderate (it amplifies any
    error by the largest one); ``max_multiplier_for_periodicity`` says by how much.
    """
    from scipy.integrate import solve_ivp

    x = np.asarray(x, dtype=float)
    U, T = self.split(x)
    q = self.params_at(p)
    d = self.dim
    s = self._solve(x, p)
    Jn = np.linalg.norm(self.vf.jac(s["Y"], q), ord=2, axis=(-2, -1)).max(axis=1)
    k = np.maximum(1, np.ceil(self.h * T * Jn)).astype(int)
    t = np.concatenate([self.tau[j] + self.h[j] * np.arange(k[j]) / k[j]
                        for j in range(self.ntst)] + [[1.0]])
    u, _ = self.evaluate(x, p, t)
    u[-1] = U[0]
    dt = np.diff(t) * T
    m = dt.size

    def rhs_all(_: float, z: Array) -> Array:
        return (dt[:, None] * self.vf.f(z.reshape(m, d), q)).ravel()

    sol = solve_ivp(rhs_all, (0.0, 1.0), u[:-1].ravel(), method="DOP853", rtol=rtol,
                    atol=rtol * 1e-2)
    end = sol.y[:, -1].reshape(m, d)
    defect = float(np.max(np.abs(end - u[1:])))
    one = solve_ivp(lambda _, v: self.vf.f(v[None, :], q)[0], (0.0, T), U[0],
                    method="DOP853", rtol=rtol, atol=rtol * 1e-2)
    per = float(np.max(np.abs(one.y[:, -1] - U[0])))
    return {"interval_defect": defect, "periodicity_residual": per,
            "verify_pieces": float(m)}
