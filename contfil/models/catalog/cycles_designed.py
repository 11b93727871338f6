"""A cycle branch with a fold, a pitchfork, a period doubling and a torus
bifurcation at exactly known parameter values.

Designed so every Floquet multiplier is known in closed form (no single
published system has all four at exact values). State
``u = (x, y, w1, w2, w3, w4, w5)``, ``r² = x² + y²``, ``cos θ = x/r``,
``sin θ = y/r``, parameter ``p``:

- planar cycle: ``ṙ = r (p + r² - r⁴)``, ``θ̇ = Ω(r) = ω + b r²`` — a
  subcritical Hopf at ``p = 0`` whose cycles ``r² = (1 ± √(1 + 4p))/2`` meet
  at a **fold of cycles at p = -1/4** (``r² = 1/2``); radial exponent
  ``2 r² (1 - 2 r²)``, period ``T = 2π/Ω``;
- pitchfork mode: ``ẇ1 = (c_bp - p) w1 - w1³`` — multiplier
  ``exp((c_bp - p) T)`` through +1 at **p = c_bp** (``w1 -> -w1`` symmetric:
  a branch point of cycles; the new cycles have ``w1² = c_bp - p``);
- Möbius pair ``w = (w2, w3)``: ``ẇ = [s I + d Q(θ) + (Ω/2) J] w - |w|² w``
  with ``Q(θ) = [[cos θ, sin θ], [sin θ, -cos θ]]``, ``σ1 = -1``,
  ``σ2 = c_pd - p``, ``s = (σ1 + σ2)/2``, ``d = (σ1 - σ2)/2``. In the frame
  ``w = R(θ/2) (α, β)`` it reads ``α̇ = σ1 α - ..., β̇ = σ2 β - ...``, and
  ``R(π) = -I`` after one turn: multipliers ``-exp(σ1 T), -exp(σ2 T)`` —
  **period doubling at p = c_pd**; the doubled cycle has ``β² = c_pd - p``;
- torus pair ``w4 + i w5``: ``ż = (c_tr - p + i ν) z - |z|² z`` — multipliers
  ``exp((c_tr - p ± iν) T)``: **Neimark–Sacker at p = c_tr**, rotation
  angle ``ν T``.

On the cycle all transverse modes vanish and decouple, so the multipliers
above are exact for the flow (the Radau flow reproduces them to O(h⁵)).
"""

from __future__ import annotations

import numpy as np

from contfil.protocol import FunctionModel

PARAMS = ("p", "omega", "b", "c_bp", "c_pd", "c_tr", "nu")
DEFAULTS = {"p": 1.5, "omega": 1.0, "b": 0.2, "c_bp": 0.4, "c_pd": 0.8, "c_tr": 1.2, "nu": 0.9}


def designed_rhs(u: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Vector field of the designed 7-dimensional system."""
    p, om, b, cbp, cpd, ctr, nu = q
    x, y, w1, w2, w3, w4, w5 = u
    r2 = x * x + y * y
    g = p + r2 - r2 * r2
    Om = om + b * r2
    s1, s2 = -1.0, cpd - p
    s, d = 0.5 * (s1 + s2), 0.5 * (s1 - s2)
    # Q(θ) needs cos θ = x/r and sin θ = y/r (single-valued, unlike θ/2)
    r = np.sqrt(r2)
    ct, st = x / r, y / r
    m2 = w2 * w2 + w3 * w3
    m4 = w4 * w4 + w5 * w5
    return np.array(
        [
            g * x - Om * y,
            Om * x + g * y,
            (cbp - p) * w1 - w1**3,
            (s + d * ct) * w2 + (d * st - 0.5 * Om) * w3 - m2 * w2,
            (d * st + 0.5 * Om) * w2 + (s - d * ct) * w3 - m2 * w3,
            (ctr - p) * w4 - nu * w5 - m4 * w4,
            nu * w4 + (ctr - p) * w5 - m4 * w5,
        ]
    )


def designed_jacobian(u: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Analytic Jacobian of :func:`designed_rhs`."""
    p, om, b, cbp, cpd, ctr, nu = q
    x, y, w1, w2, w3, w4, w5 = u
    r2 = x * x + y * y
    r = np.sqrt(r2)
    g = p + r2 - r2 * r2
    gp = 1.0 - 2.0 * r2  # dg/d(r2)
    Om = om + b * r2
    J = np.zeros((7, 7))
    J[0, 0] = g + x * 2 * x * gp - y * 2 * b * x
    J[0, 1] = -Om + x * 2 * y * gp - y * 2 * b * y
    J[1, 0] = Om + x * 2 * b * x + y * 2 * x * gp
    J[1, 1] = g + x * 2 * b * y + y * 2 * y * gp
    J[2, 2] = (cbp - p) - 3 * w1 * w1
    s1, s2 = -1.0, cpd - p
    s, d = 0.5 * (s1 + s2), 0.5 * (s1 - s2)
    ct, st = x / r, y / r
    # derivatives of cos θ, sin θ, Ω with respect to x, y
    dct = np.array([y * y, -x * y]) / r**3
    dst = np.array([-x * y, x * x]) / r**3
    dOm = np.array([2 * b * x, 2 * b * y])
    m2 = w2 * w2 + w3 * w3
    J[3, 0:2] = d * w2 * dct + d * w3 * dst - 0.5 * w3 * dOm
    J[4, 0:2] = d * w2 * dst + 0.5 * w2 * dOm - d * w3 * dct
    J[3, 3] = s + d * ct - m2 - 2 * w2 * w2
    J[3, 4] = d * st - 0.5 * Om - 2 * w2 * w3
    J[4, 3] = d * st + 0.5 * Om - 2 * w3 * w2
    J[4, 4] = s - d * ct - m2 - 2 * w3 * w3
    m4 = w4 * w4 + w5 * w5
    J[5, 5] = (ctr - p) - m4 - 2 * w4 * w4
    J[5, 6] = -nu - 2 * w4 * w5
    J[6, 5] = nu - 2 * w5 * w4
    J[6, 6] = (ctr - p) - m4 - 2 * w5 * w5
    return J


def designed_cycles(**params: float) -> FunctionModel:
    """The designed system as a model (parameters ``p, omega, b, c_bp, c_pd, c_tr, nu``)."""
    vals = {**DEFAULTS, **params}
    unknown = set(vals) - set(PARAMS)
    if unknown:
        raise KeyError(f"designed_cycles: unknown parameters {sorted(unknown)}; known {PARAMS}")

    def obs(u: np.ndarray, q: np.ndarray) -> dict:
        return {"r": float(np.hypot(u[0], u[1])), "w1": float(u[2]),
                "w_pd": float(np.hypot(u[3], u[4])), "norm": float(np.linalg.norm(u))}

    u0 = np.zeros(7)
    return FunctionModel(designed_rhs, 7, {k: vals[k] for k in PARAMS}, name="designed_cycles",
                         jacobian=designed_jacobian, u0=u0, observables=obs)


def exact_radius2(p: float, branch: int = +1) -> float:
    """``r²`` of the planar cycle (outer branch +1, inner -1)."""
    return 0.5 * (1 + branch * np.sqrt(1 + 4 * p))


def exact_multipliers(p: float, branch: int = +1, **params: float) -> dict:
    """Exact period and the 7 Floquet multipliers of the planar cycle at ``p``."""
    q = {**DEFAULTS, **params}
    r2 = exact_radius2(p, branch)
    T = 2 * np.pi / (q["omega"] + q["b"] * r2)
    lam_r = 2 * r2 * (1 - 2 * r2)
    mults = np.array(
        [
            1.0,
            np.exp(lam_r * T),
            np.exp((q["c_bp"] - p) * T),
            -np.exp(-1.0 * T),
            -np.exp((q["c_pd"] - p) * T),
            np.exp((q["c_tr"] - p) * T + 1j * q["nu"] * T),
            np.exp((q["c_tr"] - p) * T - 1j * q["nu"] * T),
        ]
    )
    return {"r2": r2, "period": T, "multipliers": mults}


def cycle_state(p: float, branch: int = +1) -> np.ndarray:
    """The exact cycle's state at phase 0 (``x = r, y = 0``, transverse modes 0)."""
    u = np.zeros(7)
    u[0] = np.sqrt(exact_radius2(p, branch))
    return u
