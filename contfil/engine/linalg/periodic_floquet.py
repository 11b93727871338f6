"""Floquet multipliers of a periodic product of matrices, never formed.

Multiple shooting gives the monodromy of a periodic orbit as the product
``P = M_{m-1} ... M_1 M_0`` of the segment Jacobians (the drift ``exp(θL)``
folded into the last one). Forming ``P`` is what single shooting does, and it
ruins the small multipliers: the entries of ``P`` reach the largest
multiplier ``|μ_1|``, so every eigenvalue carries an absolute round-off error
``~ ε |μ_1|`` (at ``μ_1 = 1e9`` a multiplier ``1e-3`` has no correct digit).

Here the eigenvalues come from the *cyclic* matrix ``C`` (``M_i`` maps block
``i`` to block ``i+1``, ``M_{m-1}`` maps back to block 0)::

        [ 0                 M_{m-1} ]
        [ M_0   0                   ]
    C = [      M_1   0              ]
        [            ...   ...      ]

``C^m`` is block diagonal with the cyclic products of the blocks on its
diagonal, so ``λ`` is an eigenvalue of ``C`` exactly when ``λ^m`` is a
multiplier, and each multiplier gives ``m`` of them, ``λ ω^k`` (``ω =
e^{2πi/m}``), with eigenvector blocks ``w_{i+1} = M_i w_i / λ``. A
backward-stable eigensolver on ``C`` works with blocks of norm
``~ |μ_1|^{1/m}``: the error of ``λ`` is ``ε |μ_1|^{1/m}``, that of ``μ =
λ^m`` relative ``m ε |μ_1|^{1/m} / |λ|``, at every modulus (the periodic
Schur form reaches the same accuracy at ``O(m d³)`` cost instead of
``O(m³ d³)``; for the sizes of multiple shooting, ``m d`` of a few hundred,
the dense cyclic matrix is cheaper to get right).

The trivial multipliers (time shift ``f(u_i)``, symmetry ``L u_i``) are
deflated segment by segment: in orthonormal bases ``[Q_i, P_i]`` at each
segment start, ``Q_i`` spanning the trivial directions there, the blocks are
block upper triangular up to the invariance defect ``|P_{i+1}ᵀ M_i Q_i|``;
the trivial multipliers are those of the small products ``Q_{i+1}ᵀ M_i Q_i``
(rank ≤ 2, values ≈ 1, harmless to multiply) and the others the cyclic
eigenvalues of ``P_{i+1}ᵀ M_i P_i``, however close to 1 they are (the same
rule as :func:`~contfil.engine.linalg.floquet.floquet_from_blocks`, which
this reduces to for ``m = 1``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from contfil.engine.linalg.floquet import _block_trivial_spans, _sort_leading, stability_from_parts
from contfil.engine.problems.base import Stability

Array = NDArray[np.float64]
CArray = NDArray[np.complex128]

__all__ = ["cyclic_eigs", "periodic_floquet"]


def _cyclic_matrix(blocks: Sequence[Array]) -> Array:
    m = len(blocks)
    d = blocks[0].shape[0]
    C = np.zeros((m * d, m * d), dtype=np.result_type(*blocks))
    for i, B in enumerate(blocks):
        j = (i + 1) % m
        C[j * d:(j + 1) * d, i * d:(i + 1) * d] = B
    return C


def _families(lam: CArray, m: int) -> list[list[int]]:
    """Group the eigenvalues of the cyclic matrix into families ``{λ ω^k}``
    (greedy, largest modulus first, nearest unassigned sibling)."""
    omega = np.exp(2j * np.pi * np.arange(1, m) / m)
    free = np.ones(lam.size, dtype=bool)
    out: list[list[int]] = []
    for k in np.argsort(-np.abs(lam), kind="stable"):
        if not free[k]:
            continue
        fam = [int(k)]
        free[k] = False
        for w in omega:
            cand = np.flatnonzero(free)
            if cand.size == 0:
                break
            s = int(cand[np.argmin(np.abs(lam[cand] - lam[k] * w))])
            free[s] = False
            fam.append(s)
        out.append(fam)
    return out


def _cyclic(blocks: Sequence[Array]) -> tuple[CArray, CArray, CArray, Array]:
    """``(mu, lam, W, res)``: the multipliers, the representative root ``λ``
    of each (the family member nearest the positive real axis, so a real
    positive ``μ`` comes out real), its cyclic eigenvector ``W[:, j]`` (all
    ``m`` blocks) and the residual ``|C w - λ w| / |w|``."""
    m = len(blocks)
    d = blocks[0].shape[0]
    if d == 0:
        z = np.zeros(0, complex)
        return z, z, np.zeros((0, 0), complex), np.zeros(0)
    C = _cyclic_matrix(blocks)
    lam, W = np.linalg.eig(C)
    lam = lam.astype(complex)
    W = W.astype(complex)
    if m == 1:
        fams = [[k] for k in range(lam.size)]
    else:
        fams = _families(lam, m)
    reps = np.array([min(f, key=lambda i: (abs(np.angle(lam[i])), -lam[i].imag)) for f in fams],
                    dtype=int)
    lam_r = lam[reps]
    W_r = W[:, reps]
    res = np.linalg.norm(C @ W_r - W_r * lam_r, axis=0) / np.linalg.norm(W_r, axis=0)
    mu = lam_r ** m
    return mu, lam_r, W_r, res


def cyclic_eigs(blocks: Sequence[Array]) -> tuple[CArray, CArray, float]:
    """Eigenvalues and eigenvectors of ``P = B_{m-1} ... B_1 B_0`` without forming ``P``.

    Parameters
    ----------
    blocks:
        The ``m`` square factors, ``B_0`` first.

    Returns
    -------
    (mu, vectors, residual)
        The ``d`` eigenvalues of ``P`` sorted by decreasing modulus, unit
        eigenvectors of ``P`` (block 0 of the cyclic eigenvectors) and the
        largest cyclic residual ``|C w - λ w| / |w|``.
    """
    blocks = [np.asarray(B) for B in blocks]
    d = blocks[0].shape[0]
    mu, _, W, res = _cyclic(blocks)
    V = W[:d]
    V = V / np.maximum(np.linalg.norm(V, axis=0, keepdims=True), 1e-300)
    order = _sort_leading(mu)
    return mu[order], V[:, order], float(np.max(res)) if res.size else 0.0


def _complement(Q: Array) -> Array:
    k, r = Q.shape
    if r == 0:
        return np.eye(k)
    return np.linalg.svd(np.eye(k) - Q @ Q.T)[0][:, : k - r]


def _deflated_cyclic(
    Ms: Sequence[Array], Qs: Sequence[Array]
) -> tuple[CArray, CArray, NDArray[np.bool_], Array, float, int]:
    """Multipliers of one block set with the trivial spans ``Qs[i]`` (at each
    segment start) deflated. Returns ``(values, vectors at segment 0 in block
    coordinates, trivial, residuals, defect, rank)``."""
    m = len(Ms)
    k = Ms[0].shape[0]
    r = min(Q.shape[1] for Q in Qs)
    Qs = [Q[:, :r] for Q in Qs]
    Ps = [_complement(Q) for Q in Qs]
    R = [Qs[(i + 1) % m].T @ Ms[i] @ Qs[i] for i in range(m)]
    S = [Ps[(i + 1) % m].T @ Ms[i] @ Ps[i] for i in range(m)]
    X = [Qs[(i + 1) % m].T @ Ms[i] @ Ps[i] for i in range(m)]
    defect = max((float(np.linalg.norm(Ps[(i + 1) % m].T @ Ms[i] @ Qs[i])) for i in range(m)),
                 default=0.0) if k > r and r > 0 else 0.0
    # trivial multipliers: the r x r product (values ~ 1; no large entries)
    Rp = np.eye(r)
    for Ri in R:
        Rp = Ri @ Rp
    tv, tY = np.linalg.eig(Rp) if r else (np.zeros(0, complex), np.zeros((0, 0), complex))
    if k > r:
        nv, lam, W, res = _cyclic(S)
    else:
        nv, lam, W, res = (np.zeros(0, complex), np.zeros(0, complex),
                           np.zeros((0, 0), complex), np.zeros(0))
    kr = k - r
    Xn = np.zeros((k, nv.size), complex)
    for j in range(nv.size):
        s = [W[i * kr:(i + 1) * kr, j] for i in range(m)]
        x = Ps[0] @ s[0]
        if r:
            # lift: λ z_{i+1} = R_i z_i + X_i s_i, a small cyclic system
            A = lam[j] * np.eye(m * r, dtype=complex) - _cyclic_matrix(R).astype(complex)
            b = np.concatenate([X[(i - 1) % m] @ s[(i - 1) % m] for i in range(m)])
            if np.linalg.cond(A) < 1e12:  # else μ sits on a trivial one: keep P s
                z = np.linalg.solve(A, b)
                x = x + Qs[0] @ z[:r]
        Xn[:, j] = x
    vals = np.concatenate([tv.astype(complex), nv])
    V = np.column_stack([(Qs[0] @ tY).astype(complex), Xn]) if vals.size else np.zeros((k, 0))
    triv = np.concatenate([np.ones(tv.size, bool), np.zeros(nv.size, bool)])
    resid = np.concatenate([np.zeros(tv.size), res])
    return vals, V, triv, resid, defect, r


def periodic_floquet(
    block_sets: Sequence[tuple[Sequence[Array], Array]],
    directions: Sequence[Sequence[Array]] = (),
    nev: int = 13,
    period: float | None = None,
    labels: Sequence[str] | None = None,
) -> Stability:
    """All Floquet multipliers from the segment Jacobians of multiple shooting.

    Parameters
    ----------
    block_sets:
        ``(Ms, B)`` pairs as the blocks of
        :func:`~contfil.engine.linalg.floquet.floquet_from_blocks`, with one
        matrix per segment: ``Ms[i]`` (``k x k``, in the columns of ``B``)
        maps segment start ``i`` to start ``i + 1`` (the last one back to
        start 0, drift included). The first set spans an invariant subspace
        (e.g. the in-plane block of a planar orbit), a later one its quotient.
    directions:
        Per segment start, the trivial directions there (``f(u_i)``,
        ``L u_i``, full coordinates); empty: nothing deflated.
    nev:
        Number of leading non-trivial values whose residual is reported.
    period:
        If given, ``info["exponents"] = log(μ)/T``.
    labels:
        Optional name per block set (``info["block_label"]``).

    Returns
    -------
    Stability
        Multipliers sorted leading first, unit eigenvectors at segment start
        0 (full coordinates), ``residual`` the largest cyclic residual of the
        ``nev`` leading non-trivial values, ``info["method"] = "cyclic"``.
    """
    if labels is not None and len(labels) != len(block_sets):
        raise ValueError(f"periodic_floquet: {len(labels)} labels for {len(block_sets)} sets")
    m = len(block_sets[0][0])
    if any(len(Ms) != m for Ms, _ in block_sets):
        raise ValueError("periodic_floquet: every block set needs one block per segment")
    bases = [(None, np.asarray(B, dtype=float)) for _, B in block_sets]
    if len(directions):
        if len(directions) != m:
            raise ValueError(f"periodic_floquet: trivial directions for {len(directions)} "
                             f"segment starts, expected {m}")
        spans = [_block_trivial_spans(bases, list(D)) for D in directions]
    else:
        spans = [[np.zeros((np.asarray(B).shape[1], 0)) for _, B in block_sets]] * m
    parts, ranks = [], []
    for b, (Ms, B) in enumerate(block_sets):
        Ms = [np.asarray(M, dtype=float) for M in Ms]
        w, Y, triv, res, defect, r = _deflated_cyclic(Ms, [sp[b] for sp in spans])
        Xf = np.asarray(B, dtype=float) @ Y
        Xf = Xf / np.maximum(np.linalg.norm(Xf, axis=0, keepdims=True), 1e-300)
        parts.append((w, Xf, res, triv, defect))
        ranks.append(r)
    return stability_from_parts(
        parts, nev, period, labels,
        info={"method": "cyclic", "segments": m,
              "blocks": [int(np.asarray(B).shape[1]) for _, B in block_sets]},
        ranks=ranks)
