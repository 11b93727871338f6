"""Published systems whose cycle branches have documented bifurcation values.

Adaptive control system of Lur'e type (MatCont documentation, "Adaptive
control example", eq. (54); also Kuznetsov, *Elements of Applied Bifurcation
Theory*, 3rd ed., Example 5.4; used as the ``adaptx`` test run of MatCont):

    ẋ = y,   ẏ = z,   ż = -α z - β y - x + x²

The origin has characteristic polynomial ``λ³ + α λ² + β λ + 1``, so for
``β = 1`` it has a Hopf point at ``α = 1`` with ``ω = 1`` (``T = 2π``); the
first Lyapunov coefficient is negative and the stable cycles exist for
``α < 1``. MatCont's cycle continuation from that Hopf point reports a period
doubling at ``α = 0.6303020`` with period ``6.364071`` (values quoted in
docs/cycles.md, section "Published systems").
"""

from __future__ import annotations

import numpy as np

from contfil.models.protocol import FunctionModel

LURE_PARAMS = ("alpha", "beta")


def lure_rhs(u: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Vector field of the adaptive-control (Lur'e) system."""
    alpha, beta = q
    x, y, z = u
    return np.array([y, z, -alpha * z - beta * y - x + x * x])


def lure_jacobian(u: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Analytic Jacobian of :func:`lure_rhs`."""
    alpha, beta = q
    x = u[0]
    return np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [-1.0 + 2.0 * x, -beta, -alpha]])


def lure_adaptive_control(alpha: float = 1.2, beta: float = 1.0) -> FunctionModel:
    """The Lur'e adaptive-control system as a model (parameters ``alpha, beta``)."""
    if not (np.isfinite(alpha) and np.isfinite(beta)):
        raise ValueError(f"lure_adaptive_control: non-finite parameters alpha={alpha}, beta={beta}")

    def obs(u: np.ndarray, q: np.ndarray) -> dict:
        return {"x": float(u[0]), "norm": float(np.linalg.norm(u))}

    return FunctionModel(lure_rhs, 3, {"alpha": float(alpha), "beta": float(beta)},
                         name="lure_adaptive_control", jacobian=lure_jacobian, u0=np.zeros(3),
                         observables=obs)
