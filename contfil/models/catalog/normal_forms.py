"""Normal forms with closed-form bifurcation points.

Each factory returns a :class:`CatalogEntry`: the model (a
:class:`~contfil.protocol.FunctionModel` with its exact Jacobian), the
continuation parameter, a starting point and the exact answers.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from contfil.protocol import ContinuousSymmetry, FunctionModel, Symmetries

Array = NDArray[np.float64]


@dataclass
class CatalogEntry:
    """A textbook system with its exactly known answers.

    Attributes
    ----------
    model:
        The model (``FunctionModel``).
    param:
        Name of the continuation parameter.
    u0, p0:
        A solution to start from.
    exact:
        Exact answers (keys documented by each factory).
    """

    model: FunctionModel
    param: str
    u0: Array
    p0: float
    exact: dict[str, Any] = field(default_factory=dict)


def pitchfork(p0: float = -1.0) -> CatalogEntry:
    """``u' = mu u - u^3``: branch point at ``mu = 0``; branches ``u = 0`` and
    ``u = +-sqrt(mu)`` (``exact["branch"](mu)`` gives the positive one)."""
    m = FunctionModel(
        lambda u, p: p[0] * u - u**3,
        dim=1,
        params={"mu": p0},
        name="pitchfork",
        jacobian=lambda u, p: np.array([[p[0] - 3.0 * u[0] ** 2]]),
        symmetries=Symmetries(reflections={"u->-u": -np.eye(1)}),
    )
    return CatalogEntry(m, "mu", np.zeros(1), p0, {"bp": 0.0, "branch": lambda mu: np.sqrt(mu)})


def transcritical(p0: float = -1.0) -> CatalogEntry:
    """``u' = mu u - u^2``: branch point at ``mu = 0`` where ``u = 0`` and
    ``u = mu`` exchange stability."""
    m = FunctionModel(
        lambda u, p: p[0] * u - u**2,
        dim=1,
        params={"mu": p0},
        name="transcritical",
        jacobian=lambda u, p: np.array([[p[0] - 2.0 * u[0]]]),
    )
    return CatalogEntry(m, "mu", np.zeros(1), p0, {"bp": 0.0, "branch": lambda mu: mu})


def saddle_node(p0: float = -1.0) -> CatalogEntry:
    """``u' = mu + u^2`` continued from ``u = -sqrt(-mu)``: fold at ``mu = 0``,
    ``u = 0`` (stable lower branch, unstable upper)."""
    m = FunctionModel(
        lambda u, p: p[0] + u**2,
        dim=1,
        params={"mu": p0},
        name="saddle_node",
        jacobian=lambda u, p: np.array([[2.0 * u[0]]]),
    )
    return CatalogEntry(m, "mu", np.array([-np.sqrt(-p0)]), p0, {"fold": 0.0, "u_fold": 0.0})


def z2_pitchfork(p0: float = -1.0) -> CatalogEntry:
    """A 2-D system with the reflection ``(x, y) -> (-x, y)``::

        x' = mu x - x^3 + x y,     y' = -y - x^2

    Trivial branch ``(0, 0)``; pitchfork at ``mu = 0``; nontrivial branches
    ``x = +-sqrt(mu/2)``, ``y = -mu/2`` (stable, Jacobian determinant ``2 mu``).
    """

    def f(u: Array, p: Array) -> Array:
        x, y = u
        return np.array([p[0] * x - x**3 + x * y, -y - x**2])

    def jac(u: Array, p: Array) -> Array:
        x, y = u
        return np.array([[p[0] - 3 * x**2 + y, x], [-2 * x, -1.0]])

    m = FunctionModel(
        f,
        2,
        {"mu": p0},
        name="z2_pitchfork",
        jacobian=jac,
        symmetries=Symmetries(reflections={"x->-x": np.diag([-1.0, 1.0])}),
    )
    return CatalogEntry(
        m,
        "mu",
        np.zeros(2),
        p0,
        {"bp": 0.0, "branch": lambda mu: np.array([np.sqrt(mu / 2.0), -mu / 2.0])},
    )


def hopf_2d(omega: float = 2.0, p0: float = -1.0) -> CatalogEntry:
    """Hopf normal form ``z' = (mu + i omega) z - |z|^2 z`` in real form:
    eigenvalues ``mu +- i omega`` on ``u = 0``, Hopf at ``mu = 0``."""

    def f(u: Array, p: Array) -> Array:
        x, y = u
        r2 = x * x + y * y
        return np.array([p[0] * x - p[1] * y - r2 * x, p[1] * x + p[0] * y - r2 * y])

    def jac(u: Array, p: Array) -> Array:
        x, y = u
        r2 = x * x + y * y
        return np.array(
            [[p[0] - r2 - 2 * x * x, -p[1] - 2 * x * y], [p[1] - 2 * x * y, p[0] - r2 - 2 * y * y]]
        )

    m = FunctionModel(f, 2, {"mu": p0, "omega": omega}, name="hopf_2d", jacobian=jac)
    return CatalogEntry(m, "mu", np.zeros(2), p0, {"hopf": 0.0, "omega": omega})


def bautin_2d(p0: float = -0.5, beta2: float = 1.0, omega: float = 1.0) -> CatalogEntry:
    """Bautin normal form ``z' = (mu + i omega) z + beta2 |z|^2 z - |z|^4 z``:
    Hopf at ``mu = 0`` (subcritical for ``beta2 > 0``), cycles ``r^2 = rho``
    with ``mu + beta2 rho - rho^2 = 0`` (period ``2 pi / omega``), folds of
    cycles on the curve ``mu = -beta2^2 / 4`` at ``rho = beta2 / 2`` (two
    parameters ``mu``, ``beta2``: the textbook LPC curve)."""

    def f(u: Array, p: Array) -> Array:
        x, y = u
        r2 = x * x + y * y
        g = p[0] + p[1] * r2 - r2 * r2
        return np.array([g * x - p[2] * y, p[2] * x + g * y])

    def jac(u: Array, p: Array) -> Array:
        x, y = u
        r2 = x * x + y * y
        g = p[0] + p[1] * r2 - r2 * r2
        gr = p[1] - 2 * r2
        return np.array([[g + 2 * x * x * gr, 2 * x * y * gr - p[2]],
                         [2 * x * y * gr + p[2], g + 2 * y * y * gr]])

    m = FunctionModel(f, 2, {"mu": p0, "beta2": beta2, "omega": omega}, name="bautin_2d",
                      jacobian=jac)
    return CatalogEntry(m, "mu", np.zeros(2), p0,
                        {"hopf": 0.0, "cycle_fold": -beta2**2 / 4, "omega": omega})


def o2_hopf(omega: float = 1.5, a: float = -1.0, b: float = -2.0, p0: float = -1.0) -> CatalogEntry:
    """O(2)-equivariant Hopf normal form in C^2 = R^4::

        z1' = (mu + i omega) z1 + (a |z1|^2 + b |z2|^2) z1
        z2' = (mu + i omega) z2 + (a |z2|^2 + b |z1|^2) z2

    with ``u = (Re z1, Im z1, Re z2, Im z2)``. On ``u = 0`` the eigenvalue
    ``mu + i omega`` is double: two identical pairs cross at ``mu = 0``
    (a symmetry-forced double Hopf point). The circle symmetry acts by
    ``(z1, z2) -> (e^{i phi} z1, e^{-i phi} z2)`` and the swap ``z1 <-> z2``.
    """

    def f(u: Array, p: Array) -> Array:
        z1 = u[0] + 1j * u[1]
        z2 = u[2] + 1j * u[3]
        lam = p[0] + 1j * p[1]
        d1 = lam * z1 + (a * abs(z1) ** 2 + b * abs(z2) ** 2) * z1
        d2 = lam * z2 + (a * abs(z2) ** 2 + b * abs(z1) ** 2) * z2
        return np.array([d1.real, d1.imag, d2.real, d2.imag])

    gen = np.zeros((4, 4))
    gen[0, 1], gen[1, 0] = -1.0, 1.0
    gen[2, 3], gen[3, 2] = 1.0, -1.0
    sym = Symmetries(
        continuous=[ContinuousSymmetry("phase_shift", gen)],
        reflections={
            "swap": np.block([[np.zeros((2, 2)), np.eye(2)], [np.eye(2), np.zeros((2, 2))]])
        },
    )
    m = FunctionModel(f, 4, {"mu": p0, "omega": omega}, name="o2_hopf", symmetries=sym)
    return CatalogEntry(m, "mu", np.zeros(4), p0, {"hopf": 0.0, "omega": omega, "multiplicity": 2})


def hopf_with_real_pair(
    omega: float = 3.0,
    delta: float = 0.01,
    n_damped: int = 0,
    kappa: tuple[float, float] = (0.2, 0.6),
    p0: float = -0.3,
) -> CatalogEntry:
    """A Hopf pair and a double real eigenvalue crossing the other way::

        (x, y)' = Hopf normal form: eigenvalues mu +- i omega, cubic -r^2 (x, y)
        z' = (delta - mu) z - |z|^2 z,   z in R^2 (O(2): a double eigenvalue)
        w_j' = -kappa_j w_j - w_j^3,     j = 1..n_damped (decoupled, stable)

    On ``u = 0`` the pair crosses into the right half plane at ``mu = 0``
    while the double real eigenvalue ``delta - mu`` leaves it at
    ``mu = delta``: for ``mu < 0`` and for ``delta < mu`` two eigenvalues
    are unstable, so a step over ``[0, delta]`` keeps the total unstable
    count. ``kappa_j`` spread over ``kappa``: with ``kappa`` inside
    ``(0, omega)`` the damped modes are the eigenvalues nearest the origin,
    not the critical pair. ``exact``: ``hopf = 0``, ``omega``,
    ``real_crossing = delta``.
    """
    nd = int(n_damped)
    kap = np.linspace(kappa[0], kappa[1], nd) if nd else np.zeros(0)
    n = 4 + nd

    def f(u: Array, p: Array) -> Array:
        mu = p[0]
        x, y, z1, z2 = u[:4]
        r2, q2 = x * x + y * y, z1 * z1 + z2 * z2
        out = np.empty(n)
        out[0] = mu * x - omega * y - r2 * x
        out[1] = omega * x + mu * y - r2 * y
        out[2] = (delta - mu) * z1 - q2 * z1
        out[3] = (delta - mu) * z2 - q2 * z2
        w = u[4:]
        out[4:] = -kap * w - w**3
        return out

    def jac(u: Array, p: Array) -> Array:
        mu = p[0]
        x, y, z1, z2 = u[:4]
        r2, q2 = x * x + y * y, z1 * z1 + z2 * z2
        J = np.zeros((n, n))
        J[0, :2] = [mu - r2 - 2 * x * x, -omega - 2 * x * y]
        J[1, :2] = [omega - 2 * x * y, mu - r2 - 2 * y * y]
        J[2, 2:4] = [delta - mu - q2 - 2 * z1 * z1, -2 * z1 * z2]
        J[3, 2:4] = [-2 * z1 * z2, delta - mu - q2 - 2 * z2 * z2]
        J[4:, 4:] = np.diag(-kap - 3 * u[4:] ** 2)
        return J

    m = FunctionModel(
        f, n, {"mu": p0}, name=f"hopf_with_real_pair_n{n}", jacobian=jac, u0=np.zeros(n)
    )
    return CatalogEntry(
        m, "mu", np.zeros(n), p0, {"hopf": 0.0, "omega": omega, "real_crossing": delta}
    )
