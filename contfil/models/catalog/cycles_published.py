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

Autonomous electronic circuit (Freire, Rodríguez-Luis, Gamero & Ponce, "A
case study for homoclinic chaos in an autonomous electronic circuit",
Physica D 62 (1993) 230-253; the AUTO-07p demo ``tor`` and the MatCont
manual's torus example ``torBPC``), :func:`freire_circuit`::

    ẋ = (-(β + ν) x + β y - a3 x³ + b3 (y - x)³) / r
    ẏ = β x - (β + γ) y - z - b3 (y - x)³
    ż = y + ε

with ``β = 0.5, γ = -0.6, r = 0.6, a3 = 0.32858, b3 = 0.93358`` (the values
of MatCont's ``torBPC`` run; the AUTO demo and the MatCont 7.4 text print
``0.328578, 0.933578``) and ``ν`` the continuation parameter. For ``ε = 0``
the field is odd (``u -> -u``), the origin is an equilibrium for every ``ν``
with a Hopf point at ``ν = (-43 + √799)/25 = -0.5893364780`` (characteristic
polynomial ``λ³ + (5ν/3 + 11/15) λ² + (1/2 - ν/6) λ + 5ν/3 + 5/6``), and the
symmetric cycles born there have a fold and a symmetry-breaking branch point;
the asymmetric cycles leaving the branch point have a torus bifurcation
(AUTO demo ``tor``: labels BP on the Hopf branch, TR on the branch from BP).
MatCont breaks the symmetry with ``ε = 0.001`` ("to avoid the branch point")
and, continuing the cycles from the Hopf point at ``ν = -0.589286``, prints
(MatCont manual, Govaerts, Kuznetsov, Meijer et al., section "Continuation of
torus bifurcation of limit cycles", example "an autonomous electronic
circuit"; ntst = 25, ncol = 4):

- Limit point cycle  ``ν = -0.5844928``, period ``8.411855``;
- Neimark-Sacker     ``ν = -0.5957506``, period ``8.861103``;
- Period Doubling    ``ν = -0.6146817``, period ``9.256846``.

For the symmetric system (``ε = 0``) with the AUTO demo's constants
(:data:`FREIRE_AUTO_DEMO`), the reference output of AUTO-07p's demo test suite
(file ``test/hyper.all`` of the AUTO-07p repository, section "Doing tor",
NTST = 25, NCOL = 4, 6 significant digits) prints on the cycles from the Hopf
point ``LP ν = -0.584335, T = 8.42647`` and ``BP ν = -0.587029,
T = 8.68967`` (L2-norm 0.208647), and on the branch switched at that BP
``TR ν = -0.591650, T = 8.79415`` and ``PD ν = -0.614955, T = 9.26630``.
"""

from __future__ import annotations

import numpy as np

from contfil.protocol import FunctionModel

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


FREIRE_PARAMS = ("nu", "beta", "gamma", "r", "a3", "b3", "eps")

#: The constants of the AUTO-07p demo ``tor`` (``freire_circuit(eps=0, **FREIRE_AUTO_DEMO)``).
FREIRE_AUTO_DEMO = {"a3": 0.328578, "b3": 0.933578}


def freire_rhs(u: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Vector field of the electronic circuit (parameters :data:`FREIRE_PARAMS`)."""
    nu, beta, gamma, r, a3, b3, eps = q
    x, y, z = u
    c = b3 * (y - x) ** 3
    return np.array([(-(beta + nu) * x + beta * y - a3 * x**3 + c) / r,
                     beta * x - (beta + gamma) * y - z - c,
                     y + eps])


def freire_jacobian(u: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Analytic Jacobian of :func:`freire_rhs`."""
    nu, beta, gamma, r, a3, b3, eps = q
    x, y, _ = u
    d = 3.0 * b3 * (y - x) ** 2
    return np.array([[(-(beta + nu) - 3.0 * a3 * x * x - d) / r, (beta + d) / r, 0.0],
                     [beta + d, -(beta + gamma) - d, -1.0],
                     [0.0, 1.0, 0.0]])


def freire_small_equilibrium(q: np.ndarray) -> np.ndarray:
    """The equilibrium of :func:`freire_rhs` nearest the origin (the origin for ``ε = 0``).

    ``ż = 0`` gives ``y = -ε``; ``ẋ = 0`` is then a cubic in ``x`` (real root
    nearest 0), and ``ẏ = 0`` gives ``z``.
    """
    nu, beta, gamma, r, a3, b3, eps = (float(v) for v in q)
    y = -eps
    # -(β+ν)x + βy - a3 x³ + b3 (y-x)³ = 0, expanded in powers of x
    roots = np.roots([-(a3 + b3), 3.0 * b3 * y, -(beta + nu) - 3.0 * b3 * y * y,
                      beta * y + b3 * y**3])
    real = roots[np.abs(roots.imag) <= 1e-12 * np.maximum(1.0, np.abs(roots))].real
    x = float(real[np.argmin(np.abs(real))])
    z = beta * x - (beta + gamma) * y - b3 * (y - x) ** 3
    return np.array([x, y, z])


def freire_circuit(nu: float = -0.9, beta: float = 0.5, gamma: float = -0.6, r: float = 0.6,
                   a3: float = 0.32858, b3: float = 0.93358, eps: float = 0.0) -> FunctionModel:
    """The electronic circuit of Freire et al. (1993) as a model (see the module docstring).

    ``eps = 0`` is the odd-symmetric system of the AUTO demo ``tor``;
    ``eps = 0.001`` the symmetry-broken system of the MatCont manual's example.
    ``u0`` is the equilibrium nearest the origin at the given parameters.
    """
    vals = {"nu": nu, "beta": beta, "gamma": gamma, "r": r, "a3": a3, "b3": b3, "eps": eps}
    bad = {k: v for k, v in vals.items() if not np.isfinite(v)}
    if bad:
        raise ValueError(f"freire_circuit: non-finite parameters {bad}")
    if r == 0.0:
        raise ValueError("freire_circuit: r must be non-zero (it divides the x equation)")
    q = np.array([float(vals[k]) for k in FREIRE_PARAMS])

    def obs(u: np.ndarray, qq: np.ndarray) -> dict:
        return {"x": float(u[0]), "z": float(u[2]), "norm": float(np.linalg.norm(u))}

    return FunctionModel(freire_rhs, 3, {k: float(vals[k]) for k in FREIRE_PARAMS},
                         name="freire_circuit", jacobian=freire_jacobian,
                         u0=freire_small_equilibrium(q), observables=obs)
