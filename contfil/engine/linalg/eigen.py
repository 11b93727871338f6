"""Eigenvalues of Jacobians: dense for small systems, shift-invert Arnoldi
for large ones.

All functions return a :class:`~contfil.engine.problems.base.Stability` with
eigenvalues sorted *leading first*: by decreasing real part, and for equal
real parts the member with positive imaginary part first (so a complex pair
appears as ``a+ib, a-ib``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.linalg as sla
from numpy.typing import NDArray
from scipy.sparse.linalg import ArpackNoConvergence, LinearOperator, eigs, gmres

from contfil.engine.problems.base import Stability
from contfil.errors import ConvergenceError, NonFiniteError

Array = NDArray[np.float64]


def normalise_phase(v: NDArray[np.complex128]) -> NDArray[np.complex128]:
    """Canonical phase and scale of a complex eigenvector.

    Returns ``e^{i phi} v / |v|`` with ``Re w . Im w = 0`` and
    ``|Re w| >= |Im w|`` (the phase maximising ``|Re(e^{i phi} v)|``:
    ``tan 2 phi = 2 a.b / (|b|^2 - |a|^2)`` for ``v = a + i b``), so
    ``Re(w e^{i omega t})`` starts at the largest real part. A zero vector
    is returned unchanged. The single definition (events, switching and the
    filament's own seeds use it).
    """
    a, b = v.real, v.imag
    phi = 0.5 * np.arctan2(-2.0 * (a @ b), (a @ a) - (b @ b))
    w = v * np.exp(1j * phi)
    if np.linalg.norm(w.imag) > np.linalg.norm(w.real):
        w = w * 1j
    nw = float(np.linalg.norm(w))
    return w / nw if nw > 0.0 else w


def sort_leading(values: NDArray, vectors: NDArray | None = None) -> tuple[NDArray, NDArray | None]:
    """Sort eigenvalues by decreasing real part (then decreasing imaginary part).

    Real parts are rounded to 12 significant digits for the primary key, so
    a conjugate pair whose real parts differ in the last bit still comes out
    as ``a+ib, a-ib``.
    """
    vals = np.asarray(values, dtype=complex)
    scale = max(1.0, float(np.max(np.abs(vals)))) if vals.size else 1.0
    re_key = np.round(vals.real / scale, 12)
    order = np.lexsort((-vals.imag, -re_key))
    vals = vals[order]
    if vectors is not None:
        vectors = np.asarray(vectors)[:, order]
    return vals, vectors


def dense_stability(J: Array, vectors: bool = False) -> Stability:
    """All eigenvalues of a dense matrix ``J`` (``scipy.linalg.eig``).

    Parameters
    ----------
    J:
        Square real matrix.
    vectors:
        Also return right eigenvectors (columns, unit 2-norm).
    """
    J = np.asarray(J, dtype=float)
    if not np.all(np.isfinite(J)):
        raise NonFiniteError("dense_stability: the Jacobian has non-finite entries")
    if vectors:
        w, V = sla.eig(J, check_finite=False)
    else:
        w, V = sla.eigvals(J, check_finite=False), None
    w, V = sort_leading(w, V)
    res = float("nan")
    if V is not None and w.size:
        res = float(np.max(np.linalg.norm(J @ V - V * w, axis=0)))
    return Stability(
        values=w, kind="eigenvalues", vectors=V, residual=res, info={"method": "dense"}
    )


def shift_invert_stability(
    apply_inverse: Callable[[Array], Array],
    n: int,
    sigma: complex | float,
    k: int = 8,
    *,
    vectors: bool = False,
    tol: float = 1e-10,
    matvec: Callable[[Array], Array] | None = None,
) -> Stability:
    """Leading ``k`` eigenvalues near ``sigma`` by shift-invert Arnoldi.

    Parameters
    ----------
    apply_inverse:
        ``v -> (J - sigma I)^{-1} v`` for a *real* shift ``sigma``.
    n:
        Dimension.
    sigma:
        Real shift. For a stiff dissipative system the eigenvalues that decide
        stability are the ones nearest the imaginary axis, so ``sigma = 0``
        (or a small positive value) finds them; the result is then sorted by
        real part.
    k:
        Number of eigenvalues wanted (``k < n - 1``).
    matvec:
        ``v -> J v``, used only to report the eigen-residual.
    """
    if k >= n - 1:
        raise ValueError(
            f"shift_invert_stability: k={k} must be < n-1={n - 1}; use dense_stability"
        )
    s = float(np.real(sigma))
    op = LinearOperator(
        (n, n), matvec=lambda v: apply_inverse(np.asarray(v, float).ravel()), dtype=float
    )
    nu, V = _arnoldi_lm(op, n, k, tol, f"shift-invert Arnoldi (n={n}, k={k}, sigma={s})")
    lam = s + 1.0 / nu
    lam, V = sort_leading(lam, V)
    res = _eigen_residual(matvec, lam, V)
    return Stability(
        values=lam,
        kind="eigenvalues",
        vectors=V if vectors else None,
        residual=res,
        info={"method": "shift-invert", "sigma": s, "k": k},
    )


def _arnoldi_lm(op: LinearOperator, n: int, k: int, tol: float,
                what: str) -> tuple[NDArray, NDArray]:
    """The ``k`` largest-magnitude eigenpairs of ``op`` (ARPACK), or a
    :class:`ConvergenceError` naming ``what``."""
    try:
        return eigs(op, k=k, which="LM", tol=tol, return_eigenvectors=True)
    except ArpackNoConvergence as exc:
        raise ConvergenceError(f"{what} did not converge: {exc}") from None


def _eigen_residual(matvec: Callable[[Array], Array] | None, lam: NDArray,
                    V: NDArray) -> float:
    """``max_j |J v_j - λ_j v_j|`` for complex ``v_j`` with a real ``matvec`` (NaN without)."""
    if matvec is None:
        return float("nan")
    return max(
        float(np.linalg.norm(matvec(V[:, j].real) + 1j * matvec(V[:, j].imag) - lam[j] * V[:, j]))
        for j in range(lam.size)
    )


def inverse_from_dense(J: Array, sigma: complex) -> Callable[[Array], Array]:
    """``(J - sigma I)^{-1}`` applied through one LU factorisation (``sigma``
    may be complex)."""
    lu = sla.lu_factor(J - sigma * np.eye(J.shape[0]), check_finite=False)
    return lambda v: sla.lu_solve(lu, v, check_finite=False)


def inverse_from_sparse(J, sigma: complex) -> Callable[[Array], Array]:  # noqa: ANN001
    """``(J - sigma I)^{-1}`` for a scipy sparse ``J`` through ``splu``
    (``sigma`` may be complex)."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import splu

    lu = splu(sp.csc_matrix(J - sigma * sp.identity(J.shape[0], format="csc")))
    return lu.solve


def inverse_from_jvp(
    jvp: Callable[[Array], Array], n: int, sigma: complex, rtol: float = 1e-8
) -> Callable[[Array], Array]:
    """``(J - sigma I)^{-1}`` by GMRES on a matrix-free ``jvp`` (slow: last resort).

    A finite-difference ``jvp`` is only accurate to about 1e-10 relative, so
    the default ``rtol`` stays above that floor; a solve that ends with a
    relative residual above ``1e3 rtol`` raises. A complex ``sigma`` gives
    a complex operator (two real products per application).
    """
    if complex(sigma).imag == 0.0:
        s_re = float(complex(sigma).real)
        op = LinearOperator(
            (n, n), matvec=lambda v: jvp(np.asarray(v, float).ravel()) - s_re * v
        )
    else:
        sc = complex(sigma)

        def mv_c(v: NDArray) -> NDArray:
            v = np.asarray(v, complex).ravel()
            re, im = np.ascontiguousarray(v.real), np.ascontiguousarray(v.imag)
            return jvp(re) + 1j * jvp(im) - sc * v

        op = LinearOperator((n, n), matvec=mv_c, dtype=complex)

    def solve(v: Array) -> Array:
        x, info = gmres(op, v, rtol=rtol, atol=0.0, restart=min(n, 100), maxiter=20)
        if info != 0:
            rel = float(np.linalg.norm(op @ x - v) / max(np.linalg.norm(v), 1e-300))
            if not rel <= 1e3 * rtol:
                raise ConvergenceError(
                    f"inverse_from_jvp: GMRES did not converge (relative residual {rel:.2e}, n={n})"
                )
        return x

    return solve


def complex_pairs(values: NDArray, imag_tol: float = 1e-8) -> NDArray:
    """Members with ``Im > imag_tol * max(1, |lambda|)`` (one per conjugate pair)."""
    v = np.asarray(values, dtype=complex)
    return v[v.imag > imag_tol * np.maximum(1.0, np.abs(v))]


def complex_shift_stability(
    apply_inverse: Callable[[NDArray], NDArray],
    n: int,
    sigma: complex,
    k: int = 4,
    *,
    vectors: bool = False,
    tol: float = 1e-10,
    matvec: Callable[[Array], Array] | None = None,
) -> Stability:
    """Eigenvalues of a *real* matrix nearest a complex shift ``sigma``.

    Shift-invert Arnoldi on the complex operator ``(J - sigma I)^{-1}``;
    since ``J`` is real, the conjugate of every non-real eigenvalue found is
    added (with the conjugate vector). Used to follow eigenvalues near
    ``i omega`` on the imaginary axis that are not among those nearest a
    real shift.

    Parameters
    ----------
    apply_inverse:
        ``v -> (J - sigma I)^{-1} v`` on complex vectors.
    n, sigma, k:
        Dimension, complex shift, number of eigenvalues near ``sigma``.
    matvec:
        ``v -> J v`` on real vectors, to report the eigen-residual.
    """
    if k >= n - 1:
        raise ValueError(f"complex_shift_stability: k={k} must be < n-1={n - 1}")
    sig = complex(sigma)
    op = LinearOperator(
        (n, n), matvec=lambda v: apply_inverse(np.asarray(v, complex).ravel()), dtype=complex
    )
    nu, V = _arnoldi_lm(op, n, k, tol,
                        f"complex shift-invert Arnoldi (n={n}, k={k}, sigma={sig})")
    lam = sig + 1.0 / nu
    # J is real: add the conjugates of the non-real eigenvalues.
    nonreal = np.abs(lam.imag) > 1e-9 * np.maximum(1.0, np.abs(lam))
    lam = np.concatenate([lam, np.conj(lam[nonreal])])
    V = np.concatenate([V, np.conj(V[:, nonreal])], axis=1)
    res = _eigen_residual(matvec, lam, V)
    lam, V = sort_leading(lam, V)
    return Stability(
        values=lam,
        kind="eigenvalues",
        vectors=V if vectors else None,
        residual=res,
        info={"method": "complex shift-invert", "sigma": sig, "k": k},
    )


def merge_stability(parts: list[Stability], rtol: float = 1e-6) -> Stability:
    """Union of partial spectra (e.g. shift-invert at several shifts).

    An eigenvalue of a later part within ``rtol * max(1, |lambda|)`` of a
    not-yet-matched eigenvalue of the union is the same one (matching is
    one-to-one, so a multiplicity found by one part is kept). Sorted
    leading first; ``info["shifts"]`` lists the shifts used.
    """
    vals = list(np.asarray(parts[0].values, dtype=complex))
    keep_vec = all(p.vectors is not None for p in parts)
    vecs = [parts[0].vectors[:, j] for j in range(len(vals))] if keep_vec else []
    for part in parts[1:]:
        pv = np.asarray(part.values, dtype=complex)
        used = np.zeros(len(vals), dtype=bool)
        for j, lam in enumerate(pv):
            if vals:
                d = np.abs(np.asarray(vals) - lam)
                d[used] = np.inf
                i = int(np.argmin(d))
                if d[i] <= rtol * max(1.0, abs(lam)):
                    used[i] = True
                    continue
            vals.append(lam)
            used = np.append(used, True)
            if keep_vec:
                vecs.append(part.vectors[:, j])
    V = np.stack(vecs, axis=1) if keep_vec and vecs else None
    w, V = sort_leading(np.asarray(vals, dtype=complex), V)
    res = [p.residual for p in parts if np.isfinite(p.residual)]
    return Stability(
        values=w,
        kind="eigenvalues",
        vectors=V,
        residual=max(res) if res else float("nan"),
        info={
            "method": "shift-invert (several shifts)",
            "shifts": [p.info.get("sigma") for p in parts],
        },
    )
