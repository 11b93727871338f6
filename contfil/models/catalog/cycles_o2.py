"""The O(2)-symmetric Hopf normal form: travelling (rotating) and standing waves.

Two complex amplitudes (left/right travelling waves), ``u = (x1, y1, x2, y2)``,
``z_k = x_k + i y_k``::

    ż1 = (μ + iω) z1 + (A |z1|² + B |z2|²) z1
    ż2 = (μ + iω) z2 + (A |z2|² + B |z1|²) z2,      A = ar + i ai, B = br + i bi.

Symmetries (Golubitsky, Stewart & Schaeffer vol. II, ch. XVII; Knobloch 1986):
the rotation (spatial translation) ``z1 -> e^{iφ} z1, z2 -> e^{-iφ} z2``
(generator ``L = diag(J, -J)``), the reflection ``z1 <-> z2`` and the time
shift ``z_k -> e^{iψ} z_k``. At ``μ = 0`` the trivial state has a double
pair ``±iω`` (an O(2) double Hopf point). Exact branches (``ar < 0`` etc.):

- rotating/travelling wave (TW) ``z2 = 0, |z1|² = -μ/ar``; lab frequency
  ``Ω = ω + ai |z1|²``, rotating-wave speed ``ω_RW = Ω`` (``-Ω`` for the
  ``z2`` wave); Floquet multipliers (period ``T = 2π/Ω``): ``1`` (trivial,
  one), ``exp(-2μT)``, and a pair of modulus ``exp(μ(1 - br/ar) T)``.
- standing wave (SW) ``z1 = z2``, ``|z|² = -μ/(ar + br)``; frequency
  ``ω + (ai + bi)|z|²``; multipliers ``1, 1`` (trivial, two),
  ``exp(-2μT)``, ``exp(-2μ (ar - br)/(ar + br) T)``.

Exactly one of TW/SW is stable for ``μ > 0`` (TW iff ``br < ar < 0``).
The standing wave lives in the invariant subspace ``Fix(z1 <-> z2)``
(``"standing"``), whose reduced model is a Stuart–Landau oscillator with
coefficient ``A + B``.
"""

from __future__ import annotations

import numpy as np

from contfil.protocol import (
    ContinuousSymmetry,
    FunctionModel,
    InvariantSubspace,
    Symmetries,
)

PARAMS = ("mu", "omega", "ar", "ai", "br", "bi")
J2 = np.array([[0.0, -1.0], [1.0, 0.0]])
L_O2 = np.block([[J2, np.zeros((2, 2))], [np.zeros((2, 2)), -J2]])
SWAP = np.block([[np.zeros((2, 2)), np.eye(2)], [np.eye(2), np.zeros((2, 2))]])


def o2_rhs(u: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Vector field of the O(2) Hopf normal form."""
    mu, om, ar, ai, br, bi = p[0], p[1], p[2], p[3], p[4], p[5]
    x1, y1, x2, y2 = u
    r1, r2 = x1 * x1 + y1 * y1, x2 * x2 + y2 * y2
    g1, h1 = mu + ar * r1 + br * r2, om + ai * r1 + bi * r2
    g2, h2 = mu + ar * r2 + br * r1, om + ai * r2 + bi * r1
    return np.array([g1 * x1 - h1 * y1, h1 * x1 + g1 * y1, g2 * x2 - h2 * y2, h2 * x2 + g2 * y2])


def o2_jacobian(u: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Analytic Jacobian of :func:`o2_rhs`."""
    mu, om, ar, ai, br, bi = p[0], p[1], p[2], p[3], p[4], p[5]
    x1, y1, x2, y2 = u
    r1, r2 = x1 * x1 + y1 * y1, x2 * x2 + y2 * y2
    J = np.zeros((4, 4))
    for k, (x, y, ra, rb) in enumerate(((x1, y1, r1, r2), (x2, y2, r2, r1))):
        xo, yo = (x2, y2) if k == 0 else (x1, y1)
        g, h = mu + ar * ra + br * rb, om + ai * ra + bi * rb
        i, j = 2 * k, 2 * (1 - k)
        # own-amplitude derivatives: dg = 2 ar (x dx + y dy), dh = 2 ai (...)
        J[i, i] = g + x * 2 * ar * x - y * 2 * ai * x
        J[i, i + 1] = -h + x * 2 * ar * y - y * 2 * ai * y
        J[i + 1, i] = h + x * 2 * ai * x + y * 2 * ar * x
        J[i + 1, i + 1] = g + x * 2 * ai * y + y * 2 * ar * y
        # cross-amplitude derivatives through |z_other|²
        J[i, j] = 2 * xo * (br * x - bi * y)
        J[i, j + 1] = 2 * yo * (br * x - bi * y)
        J[i + 1, j] = 2 * xo * (bi * x + br * y)
        J[i + 1, j + 1] = 2 * yo * (bi * x + br * y)
    return J


def _standing_reduced(names_defaults: dict[str, float]) -> FunctionModel:
    def f(v: np.ndarray, p: np.ndarray) -> np.ndarray:
        return o2_rhs(np.concatenate([v, v]), p)[:2]

    def jac(v: np.ndarray, p: np.ndarray) -> np.ndarray:
        J = o2_jacobian(np.concatenate([v, v]), p)
        return J[:2, :2] + J[:2, 2:]

    return FunctionModel(f, 2, names_defaults, name="o2_hopf_standing", jacobian=jac)


def o2_hopf(
    mu: float = 0.1,
    omega: float = 1.0,
    ar: float = -1.0,
    ai: float = 0.0,
    br: float = -2.0,
    bi: float = 0.0,
) -> FunctionModel:
    """The O(2) Hopf normal form as a model (parameters ``mu, omega, ar, ai, br, bi``)."""
    defaults = dict(zip(PARAMS, (mu, omega, ar, ai, br, bi), strict=True))
    standing = InvariantSubspace(
        "standing",
        embed=lambda v: np.concatenate([v, v]),
        project=lambda u: 0.5 * (u[:2] + u[2:]),
        reduced_model=lambda: _standing_reduced(defaults),
    )
    sym = Symmetries(
        continuous=[ContinuousSymmetry("translation", L_O2.copy())],
        reflections={"swap": SWAP.copy()},
        invariant_subspaces={"standing": standing},
    )

    def obs(u: np.ndarray, p: np.ndarray) -> dict:
        return {
            "norm": float(np.linalg.norm(u)),
            "abs_z1": float(np.hypot(u[0], u[1])),
            "abs_z2": float(np.hypot(u[2], u[3])),
        }

    return FunctionModel(o2_rhs, 4, defaults, name="o2_hopf", jacobian=o2_jacobian,
                         u0=np.zeros(4), symmetries=sym, observables=obs)


def exact_travelling(mu: float, omega: float, ar: float, ai: float, br: float, bi: float) -> dict:
    """Exact travelling (rotating) wave in ``z1``: amplitude, speed, multipliers."""
    r2 = -mu / ar
    Om = omega + ai * r2
    T = 2 * np.pi / abs(Om)
    sig = mu + br * r2  # growth rate of the z2 mode
    ang = (omega + bi * r2) * T
    return {"r2": r2, "omega_rw": Om, "period": T,
            "multipliers": np.array([1.0, np.exp(-2 * mu * T), np.exp(sig * T + 1j * ang),
                                     np.exp(sig * T - 1j * ang)]),
            "eigenvalues": np.array([0.0, -2 * mu, sig + 1j * (omega + bi * r2 + Om),
                                     sig - 1j * (omega + bi * r2 + Om)])}


def exact_standing(mu: float, omega: float, ar: float, ai: float, br: float, bi: float) -> dict:
    """Exact standing wave ``z1 = z2``: amplitude, period, multipliers (two trivial)."""
    r2 = -mu / (ar + br)
    T = 2 * np.pi / abs(omega + (ai + bi) * r2)
    return {"r2": r2, "period": T,
            "multipliers": np.array([1.0, 1.0, np.exp(-2 * mu * T),
                                     np.exp(-2 * mu * (ar - br) / (ar + br) * T)])}
