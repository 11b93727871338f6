"""Hopf normal forms with exactly known periodic orbits (Stuart–Landau).

``ż = (μ + iω) z + (a + i b)|z|² z + c |z|⁴ z`` with ``z = x + i y``.
In polar form ``ṙ = r (μ + a r² + c r⁴)``, ``θ̇ = ω + b r²``, so a cycle of
radius ``r`` exists where ``μ + a r² + c r⁴ = 0``; its period is
``T = 2π/|ω + b r²|`` and its non-trivial Floquet exponent is
``d/dr[r(μ + a r² + c r⁴)] = 2 a r² + 4 c r⁴`` (``= -2μ`` when ``c = 0``),
multiplier ``exp((2 a r² + 4 c r⁴) T)``.

- supercritical (``a = -1, c = 0``): ``r = √μ`` for ``μ > 0``, stable;
- subcritical with quintic saturation (``a = +1, c = -1``): ``r² = (1 ±
  √(1 + 4μ))/2``, a fold of cycles at ``μ = -1/4, r² = 1/2``; the inner
  branch (``r² < 1/2``) is unstable and bends back from the Hopf point
  ``μ = 0``, the outer one is stable.
"""

from __future__ import annotations

import numpy as np

from contfil.models.protocol import ContinuousSymmetry, FunctionModel, Symmetries

PARAMS = ("mu", "omega", "a", "b", "c")
J2 = np.array([[0.0, -1.0], [1.0, 0.0]])


def sl_rhs(u: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Vector field of the quintic Stuart–Landau oscillator."""
    x, y = u[0], u[1]
    mu, om, a, b, c = p[0], p[1], p[2], p[3], p[4]
    r2 = x * x + y * y
    g = mu + a * r2 + c * r2 * r2
    h = om + b * r2
    return np.array([g * x - h * y, h * x + g * y])


def sl_jacobian(u: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Analytic Jacobian of :func:`sl_rhs`."""
    x, y = u[0], u[1]
    mu, om, a, b, c = p[0], p[1], p[2], p[3], p[4]
    r2 = x * x + y * y
    g = mu + a * r2 + c * r2 * r2
    h = om + b * r2
    gr = a + 2 * c * r2  # dg/d(r2)
    gx, gy, hx, hy = 2 * x * gr, 2 * y * gr, 2 * b * x, 2 * b * y
    return np.array(
        [[g + x * gx - y * hx, x * gy - h - y * hy], [h + x * hx + y * gx, g + x * hy + y * gy]]
    )


def stuart_landau(
    mu: float = 0.5,
    omega: float = 1.0,
    a: float = -1.0,
    b: float = 0.0,
    c: float = 0.0,
    *,
    with_symmetry: bool = False,
) -> FunctionModel:
    """The Stuart–Landau oscillator as a model (parameters ``mu, omega, a, b, c``).

    ``with_symmetry=True`` declares the phase rotation ``z -> e^{iφ} z``
    (generator ``J2``): its cycles are then rotating waves.
    """
    sym = Symmetries(continuous=[ContinuousSymmetry("phase", J2.copy())]) if with_symmetry else None

    def obs(u: np.ndarray, p: np.ndarray) -> dict:
        return {"norm": float(np.hypot(u[0], u[1])), "u0": float(u[0])}

    return FunctionModel(
        sl_rhs,
        2,
        dict(zip(PARAMS, (mu, omega, a, b, c), strict=True)),
        name="stuart_landau",
        jacobian=sl_jacobian,
        u0=np.zeros(2),
        symmetries=sym,
        observables=obs,
    )


def subcritical_stuart_landau(mu: float = -0.1, omega: float = 1.0, b: float = 0.0) -> FunctionModel:
    """``ṙ = r(μ + r² - r⁴)``: subcritical Hopf at μ = 0, fold of cycles at μ = -1/4."""
    return stuart_landau(mu, omega, a=1.0, b=b, c=-1.0)


def cycle_radius2(mu: float, a: float, c: float, branch: int = +1) -> float:
    """Exact ``r²`` of the cycle: root of ``μ + a r² + c r⁴ = 0`` (branch ±1 when c ≠ 0)."""
    if c == 0.0:
        return -mu / a
    disc = a * a - 4 * c * mu
    return float((-a - branch * np.sqrt(disc)) / (2 * c)) if c < 0 else float(
        (-a + branch * np.sqrt(disc)) / (2 * c)
    )


def exact_cycle(mu: float, omega: float = 1.0, a: float = -1.0, b: float = 0.0, c: float = 0.0,
                branch: int = +1) -> dict[str, float]:
    """Radius, period, Floquet exponent and multiplier of the exact cycle."""
    r2 = cycle_radius2(mu, a, c, branch)
    T = 2 * np.pi / abs(omega + b * r2)
    lam = 2 * a * r2 + 4 * c * r2 * r2
    return {"r2": r2, "r": float(np.sqrt(r2)), "period": T, "exponent": lam,
            "multiplier": float(np.exp(lam * T))}
