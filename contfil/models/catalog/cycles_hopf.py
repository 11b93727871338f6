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

from contfil.protocol import ContinuousSymmetry, FunctionModel, Symmetries

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


def subcritical_stuart_landau(
    mu: float = -0.1, omega: float = 1.0, b: float = 0.0
) -> FunctionModel:
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


def stuart_landau_with_modes(
    rates: np.ndarray,
    pairs: np.ndarray | None = None,
    mu: float = 1.0,
    omega: float = 1.0,
    kappa: float = 0.5,
) -> FunctionModel:
    """Supercritical Stuart–Landau cycle with attached transverse modes of known rates.

    State ``(x, y, y_1 .. y_m, (a_1, b_1) .. (a_k, b_k))``; ``r² = x² + y²``::

        ẏ_j = (σ_j + κ (r² - μ)) y_j,
        (ȧ + i ḃ)_j = (α_j + i β_j + κ (r² - μ)) (a + i b)_j.

    The coupling ``κ`` vanishes on the cycle ``r² = μ`` (period ``2π/ω``), so
    the Floquet multipliers are exactly ``1, exp(-2μT), exp(σ_j T),
    exp((α_j ± iβ_j) T)`` — a test of many leading multipliers at once.
    ``rates`` are the ``σ_j``; ``pairs`` rows ``(α_j, β_j)``.
    """
    sig = np.asarray(rates, dtype=float)
    pr = np.zeros((0, 2)) if pairs is None else np.asarray(pairs, dtype=float).reshape(-1, 2)
    m, k = sig.size, pr.shape[0]
    dim = 2 + m + 2 * k

    def f(u: np.ndarray, p: np.ndarray) -> np.ndarray:
        out = np.empty(dim)
        out[:2] = sl_rhs(u[:2], p[:5])
        c = p[5] * (u[0] ** 2 + u[1] ** 2 - p[0])
        out[2 : 2 + m] = (sig + c) * u[2 : 2 + m]
        a, b = u[2 + m :: 2], u[3 + m :: 2]
        out[2 + m :: 2] = (pr[:, 0] + c) * a - pr[:, 1] * b
        out[3 + m :: 2] = pr[:, 1] * a + (pr[:, 0] + c) * b
        return out

    def jac(u: np.ndarray, p: np.ndarray) -> np.ndarray:
        J = np.zeros((dim, dim))
        J[:2, :2] = sl_jacobian(u[:2], p[:5])
        c = p[5] * (u[0] ** 2 + u[1] ** 2 - p[0])
        dc = 2 * p[5] * u[:2]
        idx = np.arange(2, 2 + m)
        J[idx, idx] = sig + c
        J[2:, :2] = np.outer(u[2:], dc)
        ia, ib = np.arange(2 + m, dim, 2), np.arange(3 + m, dim, 2)
        J[ia, ia] = pr[:, 0] + c
        J[ia, ib] = -pr[:, 1]
        J[ib, ia] = pr[:, 1]
        J[ib, ib] = pr[:, 0] + c
        return J

    params = {"mu": mu, "omega": omega, "a": -1.0, "b": 0.0, "c": 0.0, "kappa": kappa}
    return FunctionModel(f, dim, params, name="stuart_landau_with_modes", jacobian=jac)


def exact_multipliers_with_modes(rates: np.ndarray, pairs: np.ndarray | None, mu: float,
                                 omega: float = 1.0) -> np.ndarray:
    """Exact multipliers of :func:`stuart_landau_with_modes`, leading first."""
    T = 2 * np.pi / omega
    vals = [1.0, np.exp(-2 * mu * T)] + list(np.exp(np.asarray(rates, dtype=float) * T))
    if pairs is not None:
        for a, b in np.asarray(pairs, dtype=float).reshape(-1, 2):
            vals += [np.exp((a + 1j * b) * T), np.exp((a - 1j * b) * T)]
    v = np.asarray(vals, dtype=complex)
    return v[np.lexsort((-v.imag, -np.abs(v)))]


def two_oscillators(mu1: float = 0.5, omega1: float = 0.7, mu2: float = 0.3,
                    omega2: float = 1.0) -> FunctionModel:
    """Two uncoupled supercritical Stuart–Landau oscillators; only the first is
    acted on by the declared rotation symmetry (generator ``J2 ⊕ 0``).

    Its attractor is a genuine relative periodic orbit: in the frame rotating
    with the first oscillator (speed ``ω1``) the state repeats after
    ``T = 2π/ω2``, so ``exp(θL) φ_T(u) = u`` with drift ``θ = -ω1 T`` (mod 2π),
    amplitudes ``√μ1, √μ2``; multipliers ``1, 1`` (time shift, rotation),
    ``exp(-2μ1 T)``, ``exp(-2μ2 T)``.
    """

    def f(u: np.ndarray, p: np.ndarray) -> np.ndarray:
        a = sl_rhs(u[:2], np.array([p[0], p[1], -1.0, 0.0, 0.0]))
        b = sl_rhs(u[2:], np.array([p[2], p[3], -1.0, 0.0, 0.0]))
        return np.concatenate([a, b])

    def jac(u: np.ndarray, p: np.ndarray) -> np.ndarray:
        J = np.zeros((4, 4))
        J[:2, :2] = sl_jacobian(u[:2], np.array([p[0], p[1], -1.0, 0.0, 0.0]))
        J[2:, 2:] = sl_jacobian(u[2:], np.array([p[2], p[3], -1.0, 0.0, 0.0]))
        return J

    L = np.zeros((4, 4))
    L[:2, :2] = J2
    return FunctionModel(
        f, 4, {"mu1": mu1, "omega1": omega1, "mu2": mu2, "omega2": omega2},
        name="two_oscillators", jacobian=jac,
        symmetries=Symmetries(continuous=[ContinuousSymmetry("rotation_1", L)]),
    )
