"""Floquet multipliers by matrix-free Arnoldi on the monodromy operator.

The monodromy operator of a periodic orbit ``u`` of period ``T`` is
``M v = G Dφ_T(u) v`` (``G = exp(θL)`` for a relative periodic orbit with
drift ``θ``, the identity otherwise). Its action needs one flow evaluation
(finite differences) or one tangent integration; the matrix is never
formed. Arnoldi builds ``M V_k = V_{k+1} H`` and the Ritz values of the
square part of ``H`` approximate the multipliers of largest modulus first.

Convergence criterion (the one of the filament paper): the ``nev`` leading
Ritz values (13 by default) change by less than ``tol`` (1e-8) between two
consecutive Arnoldi iterations. The space is exhausted exactly at ``k = n``.

Trivial multipliers (``+1``, forced by the time shift along ``f(u)`` and by
each continuous symmetry along ``L u``) are identified by their
*eigenvectors*, never by closeness to 1: their eigenspace is
``span{f(u), L_1 u, ...}`` (rank 1 for a rotating wave, where ``f ∥ L u``;
rank 2 for a standing wave). By default that span is deflated (see
:func:`floquet_multipliers`); alternatively :func:`flag_trivial` flags the
Ritz vectors with the largest projection onto it. Either way a genuine
multiplier crossing +1 next to a trivial one (a branch point of cycles) is
not hidden.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from contfil.engine.linalg.krylov import arnoldi
from contfil.engine.problems.base import Stability

Array = NDArray[np.float64]
CArray = NDArray[np.complex128]

__all__ = ["arnoldi_eigs", "flag_trivial", "floquet_from_blocks", "floquet_multipliers"]

#: Krylov space invariant: the new direction is below this fraction of the
#: largest entry of ``H`` (round-off), so the Ritz values are exact.
INVARIANT_REL = 1e-13


def _sort_leading(vals: NDArray[np.complex128]) -> NDArray[np.intp]:
    # by modulus, ties (complex pairs) broken by the sign of the imaginary part
    return np.lexsort((-vals.imag, -np.round(np.abs(vals), 12)))


def _max_change(new: NDArray[np.complex128], old: NDArray[np.complex128]) -> float:
    """Largest distance from each new leading Ritz value to the old set."""
    if old.size == 0:
        return np.inf
    return float(max(np.min(np.abs(old - z)) for z in new))


def arnoldi_eigs(
    matvec: Callable[[Array], Array],
    n: int,
    nev: int = 13,
    tol: float = 1e-8,
    kmax: int | None = None,
    v0: Array | None = None,
    seed: int = 0,
    space_dim: int | None = None,
) -> tuple[NDArray[np.complex128], NDArray[np.complex128], dict[str, Any]]:
    """Leading eigenvalues of a linear operator by Arnoldi (no restart).

    Parameters
    ----------
    matvec:
        ``v -> M v`` on ``R^n``.
    nev:
        Number of leading (largest modulus) eigenvalues whose Ritz values
        must settle.
    tol:
        Stop when the ``nev`` leading Ritz values move by less than ``tol``
        between consecutive iterations (or when the space is exhausted).
    kmax:
        Maximum Krylov dimension (default ``min(n, max(3 nev, 40))``).
    space_dim:
        Dimension of the invariant space the operator acts on (``n`` unless
        the caller deflated a subspace); the Krylov space is exhausted there.

    Returns
    -------
    values, vectors, info:
        All Ritz values of the final ``H`` sorted leading first, their Ritz
        vectors (columns, unit norm), and ``info`` with ``iterations``
        (= operator applications), ``converged``, ``ritz_change`` (last
        change of the leading values) and ``residuals`` (Ritz residual
        norms ``|M x - μ x|`` of the returned pairs).
    """
    # Over 80 lines only through its docstring (~55 lines of code).
    dim = n if space_dim is None else int(space_dim)
    nev = max(1, min(int(nev), dim))
    kmax = min(dim, int(kmax) if kmax is not None else max(3 * nev, 40))
    kmax = max(kmax, 1)
    rng = np.random.default_rng(seed)
    v = rng.standard_normal(n) if v0 is None else np.array(v0, dtype=float)
    # Stop rule: the nev leading Ritz values settle, or the Krylov space is
    # invariant (then they are exact); the state lives in this closure.
    track = {"prev": np.zeros(0, dtype=complex), "change": np.inf, "converged": False}

    def settled(H: Array, k: int, hn: float) -> bool:
        vals = np.linalg.eigvals(H[:k, :k])
        lead = vals[_sort_leading(vals)][: min(nev, k)]
        if k >= nev:
            prev = track["prev"]
            track["change"] = _max_change(lead, prev) if prev.size >= lead.size else np.inf
        track["prev"] = lead
        scale = max(1.0, float(np.max(np.abs(H[: k + 1, :k]))))
        if hn <= INVARIANT_REL * scale or k == dim:
            track["converged"], track["change"] = True, 0.0
            return True
        if track["change"] < tol:
            track["converged"] = True
            return True
        return False

    V, H, k = arnoldi(matvec, v, kmax, settled, who="arnoldi_eigs")
    change, converged = track["change"], track["converged"]
    Hk = H[:k, :k]
    vals, Y = np.linalg.eig(Hk)
    order = _sort_leading(vals)
    vals, Y = vals[order], Y[:, order]
    X = V[:, :k] @ Y
    norms = np.linalg.norm(X, axis=0)
    X /= norms[None, :]
    res = np.abs(H[k, k - 1] * Y[-1, :]) / norms
    info = {
        "iterations": k,
        "converged": converged,
        "ritz_change": float(change),
        "residuals": res,
        # X = V[:, :k] @ coeffs: lets a caller rebuild M X from stored M V
        "coeffs": Y / norms[None, :],
    }
    return vals, X, info


def flag_trivial(
    values: NDArray[np.complex128],
    vectors: NDArray[np.complex128],
    directions: Sequence[Array],
    rank_tol: float = 1e-6,
    min_projection: float = 0.5,
) -> tuple[NDArray[np.bool_], dict[str, Any]]:
    """Flag the multipliers whose eigenvectors lie in ``span(directions)``.

    As many are flagged as the numerical rank of the directions (f(u) and
    L u for each symmetry). Among the Ritz vectors, those with the largest
    projection ``|Qᴴ x| / |x|`` are taken, provided it exceeds
    ``min_projection``; ``info`` reports the projections and the distance
    of the flagged values from 1 (an accuracy check, not the criterion).
    """
    trivial = np.zeros(len(values), dtype=bool)
    D = np.column_stack([np.asarray(d, dtype=float) for d in directions]) if directions else None
    if D is None or D.size == 0:
        return trivial, {"rank": 0}
    Q, R, _ = _qr_rank(D, rank_tol)
    rank = Q.shape[1]
    proj = np.linalg.norm(Q.T @ vectors, axis=0) / np.linalg.norm(vectors, axis=0)
    order = np.argsort(-proj)
    chosen = [i for i in order[:rank] if proj[i] >= min_projection]
    trivial[chosen] = True
    info = {
        "rank": rank,
        "projections": proj[chosen],
        "distance_from_one": float(np.max(np.abs(values[chosen] - 1.0))) if chosen else np.nan,
        "missing": rank - len(chosen),
    }
    return trivial, info


def _qr_rank(D: Array, tol: float) -> tuple[Array, Array, int]:
    """Orthonormal basis of ``range(D)`` after dropping dependent columns."""
    norms = np.linalg.norm(D, axis=0)
    cols = [D[:, j] / norms[j] for j in range(D.shape[1]) if norms[j] > 0]
    basis: list[Array] = []
    for c in cols:
        w = c.copy()
        for b in basis:
            w -= (b @ w) * b
        nw = float(np.linalg.norm(w))
        if nw > np.sqrt(tol):
            basis.append(w / nw)
    Q = np.column_stack(basis) if basis else np.zeros((D.shape[0], 0))
    return Q, np.zeros((0, 0)), len(basis)


def _deflated(
    apply_monodromy: Callable[[Array], Array],
    n: int,
    Q: Array,
    rank: int,
    calls: dict[str, int],
    *,
    nev: int,
    tol: float,
    kmax: int | None,
    v0: Array | None,
) -> tuple[NDArray[np.complex128], NDArray[np.complex128], NDArray[np.bool_],
           dict[str, Any], dict[str, Any]]:
    """Multipliers with the trivial span ``Q`` deflated (see
    :func:`floquet_multipliers`): the exact ``QᵀMQ`` block plus Arnoldi on
    the compressed operator, eigenvectors lifted back. Returns ``(values,
    vectors, trivial, info, trivial_info)`` sorted leading first."""
    raw: list[Array] = []

    def mvp(v: Array) -> Array:
        calls["n"] += 1
        w = np.asarray(apply_monodromy(v), dtype=float)
        raw.append(w)
        return w - Q @ (Q.T @ w)

    rng = np.random.default_rng(0)
    start = rng.standard_normal(n) if v0 is None else np.array(v0, dtype=float)
    start = start - Q @ (Q.T @ start)
    m = n - rank
    MQ = np.column_stack([np.asarray(apply_monodromy(q), dtype=float) for q in Q.T])
    calls["n"] += rank
    R = Q.T @ MQ
    if m > 0:
        nv, Y, info = arnoldi_eigs(mvp, n, nev=min(nev, m), tol=tol,
                                   kmax=kmax, v0=start, space_dim=m)
        k = info["iterations"]
        W = np.column_stack(raw[:k])
        MY = W @ info["coeffs"]
        # lift the compressed eigenvectors: x = y + Q z with (μ I - R) z = Qᵀ M y
        Xn = np.array(Y, dtype=complex)
        eye = np.eye(rank)
        for j, mu in enumerate(nv):
            A = mu * eye - R
            if np.linalg.cond(A) < 1e12:  # else μ sits on a trivial one: keep y
                Xn[:, j] = Y[:, j] + Q @ np.linalg.solve(A, Q.T @ MY[:, j])
        Xn /= np.linalg.norm(Xn, axis=0, keepdims=True)
    else:
        nv, Xn, info = np.zeros(0, complex), np.zeros((n, 0), complex), {
            "iterations": 0, "converged": True, "ritz_change": 0.0, "residuals": np.zeros(0)}
    tv, tY = np.linalg.eig(R)
    Xt = Q @ tY
    vals = np.concatenate([tv.astype(complex), nv])
    X = np.column_stack([Xt.astype(complex), Xn])
    trivial = np.concatenate([np.ones(rank, bool), np.zeros(nv.size, bool)])
    order = _sort_leading(vals)
    vals, X, trivial = vals[order], X[:, order], trivial[order]
    tinfo = {
        "rank": rank,
        "method": "deflation",
        "values": tv,
        "distance_from_one": float(np.max(np.abs(tv - 1.0))),
        # how far span{f, Lu} is from invariant (discretisation, unconverged orbit)
        "invariance_defect": float(np.linalg.norm(MQ - Q @ R)),
    }
    info["residuals"] = np.asarray(info["residuals"])
    return vals, X, trivial, info, tinfo


def floquet_multipliers(
    apply_monodromy: Callable[[Array], Array],
    n: int,
    trivial_directions: Sequence[Array] = (),
    nev: int = 13,
    tol: float = 1e-8,
    kmax: int | None = None,
    period: float | None = None,
    v0: Array | None = None,
    deflate: bool = True,
) -> Stability:
    """Floquet multipliers of a (relative) periodic orbit, matrix-free.

    Parameters
    ----------
    apply_monodromy:
        ``v -> G Dφ_T(u) v``.
    n:
        State dimension.
    trivial_directions:
        ``f(u)`` and ``L u`` per continuous symmetry.
    nev, tol, kmax:
        See :func:`arnoldi_eigs` (13 leading values converged to 1e-8).
    period:
        If given, ``info["exponents"] = log(μ)/T`` is filled.
    deflate:
        ``True`` (default): the span ``Q`` of the trivial directions is
        invariant (``M f = f``, ``M L u = L u``), so in the basis ``[Q, Q⊥]``
        the monodromy is block triangular and its spectrum is exactly that of
        ``QᵀMQ`` (the trivial multipliers, ≈ 1) together with that of the
        compressed operator ``Q⊥ᵀ M Q⊥``, on which Arnoldi runs. This is
        necessary, not cosmetic: a standing wave has the *semisimple* double
        multiplier 1, and Arnoldi from one start vector sees only one vector
        of a semisimple eigenspace. No multiplier is hidden — a genuine one
        crossing +1 (branch point, fold's Jordan partner) stays in the
        compressed spectrum. ``False``: plain Arnoldi and :func:`flag_trivial`
        by eigenvector projection.

    Returns
    -------
    Stability
        ``kind="multipliers"``, values sorted by decreasing modulus, trivial
        flags, eigenvectors (columns), ``residual`` = the largest Ritz
        residual among the ``nev`` leading non-trivial pairs, and ``info`` with
        ``iterations`` (Arnoldi steps), ``operator_applications``,
        ``converged``, ``ritz_change``, ``trivial_info``.
    """
    calls = {"n": 0}
    Q, _, rank = _qr_rank(
        np.column_stack([np.asarray(d, dtype=float) for d in trivial_directions])
        if len(trivial_directions) else np.zeros((n, 0)),
        1e-6,
    )
    if not deflate or rank == 0:

        def mv(v: Array) -> Array:
            calls["n"] += 1
            return apply_monodromy(v)

        vals, X, info = arnoldi_eigs(mv, n, nev=nev, tol=tol, kmax=kmax, v0=v0)
        trivial, tinfo = flag_trivial(vals, X, list(trivial_directions))
    else:
        vals, X, trivial, info, tinfo = _deflated(apply_monodromy, n, Q, rank, calls,
                                                  nev=nev, tol=tol, kmax=kmax, v0=v0)
    lead = min(nev, len(info["residuals"]))
    info.pop("coeffs", None)
    info["operator_applications"] = calls["n"]
    info["trivial_info"] = tinfo
    if period is not None and period > 0:
        with np.errstate(divide="ignore"):
            info["exponents"] = np.log(vals.astype(complex)) / period
    residual = float(np.max(info["residuals"][:lead])) if lead else 0.0
    return Stability(
        values=vals, kind="multipliers", trivial=trivial, vectors=X, residual=residual, info=info
    )


def _block_trivial_spans(
    blocks: Sequence[tuple[Array, Array]], directions: Sequence[Array], rank_tol: float = 1e-6
) -> list[Array]:
    """The share of ``span(directions)`` that each block's diagonal entry sees.

    In the basis ``[B_0, B_1, ...]`` the monodromy is block upper triangular
    (``B_0`` spans an invariant subspace, each later block its quotient), so
    the trivial eigenspace ``span{f, L u}`` meets the last block in the span
    of its last-block coordinates, and the combinations with no last-block
    part lie in the earlier blocks, and so on backwards. Returns per block an
    orthonormal basis (block coordinates, ``k_b x r_b``) of its trivial span;
    the ranks add up to the rank of the directions. Why per block: a
    multiplier is trivial *in the block it belongs to*, so a genuine
    multiplier crossing +1 next to a trivial one of another block can never
    take that one's place (the filament's beating pitchfork did, when the
    trivial modes were picked from all eigenvectors by their projection).
    """
    sizes = [np.asarray(B).shape[1] for _, B in blocks]
    out = [np.zeros((k, 0)) for k in sizes]
    if not len(directions):
        return out
    D = np.column_stack([np.asarray(d, dtype=float) for d in directions])
    nd = np.linalg.norm(D, axis=0)
    D = D[:, nd > 0] / nd[nd > 0]
    if D.shape[1] == 0:
        return out
    Bfull = np.column_stack([np.asarray(B, dtype=float) for _, B in blocks])
    Z = np.linalg.lstsq(Bfull, D, rcond=None)[0]
    starts = np.concatenate([[0], np.cumsum(sizes)])
    A = np.eye(D.shape[1])  # combinations of the directions not yet placed
    for b in range(len(blocks) - 1, -1, -1):
        if A.shape[1] == 0:
            break
        Zb = Z[starts[b]: starts[b + 1]] @ A
        if Zb.size == 0:
            continue
        U, sv, Vt = np.linalg.svd(Zb, full_matrices=True)
        r = int(np.sum(sv > rank_tol))
        out[b] = U[:, :r]
        A = A @ Vt[r:].T
    return out


#: the eigenvectors taken as trivial are at least this many times closer in
#: angle to the span than any other (else: a Jordan pair of a genuine
#: multiplier with a trivial one, split by the error into two eigenvectors
#: at equal angles on either side of the span, left to the deflation)
TRIVIAL_ANGLE_RATIO = 4.0
#: a deflated trivial value this close to 1 is kept
DEFLATION_OFF = 1e-6


def _deflated_block(
    M: Array, Q: Array
) -> tuple[NDArray[np.complex128], NDArray[np.complex128], NDArray[np.bool_], float]:
    """Eigenpairs of the block ``M``, its trivial multipliers those of the span ``Q``.

    The deflation (:func:`_deflation`) is exact when ``Q`` is invariant.
    The span comes from the continuous model (``f(u)``, ``L u``), so it is
    invariant under a discrete monodromy only up to the time step: on an
    orbit with a large multiplier ``λ`` an error ``δ`` in its direction
    becomes a defect ``~ λ δ``, and the deflated "trivial" value drifts far
    from 1 (dis FF's unstable beating, ``λ ≈ 400``, ``δ ≈ 4e-3``: 7.5 for
    an eigenvalue 0.954 of ``M`` whose eigenvector is within 4e-3 of ``f``).
    So when ``r`` eigenvectors of ``M`` itself are closer in angle to the
    span than every other by :data:`TRIVIAL_ANGLE_RATIO` (a strongly
    non-normal ``M`` has all its leading eigenvectors within a few degrees
    of each other: there 1e-5 against 0.15 rad), and their values are
    closer to 1 than the deflated ones, they are the trivial multipliers and
    the spectrum is ``M``'s own (only where the deflated value is off by
    more than :data:`DEFLATION_OFF` and farther from 1 than the eigenvalue:
    elsewhere the deflation is kept as it is). Near a Jordan pair (a fold or branch point
    of cycles next to a trivial multiplier) two eigenvectors lie at similar
    angles on either side of the span, and the deflation stays. Returns
    ``(values, vectors, trivial, defect)``.
    """
    vals, X, trivial, defect = _deflation(M, Q)
    k, r = M.shape[0], Q.shape[1]
    if r == 0 or k == r:
        return vals, X, trivial, defect
    w, Y = np.linalg.eig(M)
    proj = np.linalg.norm(Q.T @ Y, axis=0) / np.linalg.norm(Y, axis=0)
    sine = np.sqrt(np.clip(1.0 - proj**2, 0.0, None))
    order = np.argsort(sine)
    cand = order[:r]
    if sine[cand].max() * TRIVIAL_ANGLE_RATIO > sine[order[r]]:
        return vals, X, trivial, defect
    # only where the deflation visibly failed: its trivial value off by more
    # than DEFLATION_OFF and farther from 1 than the eigenvalue's (below
    # that its effect, e.g. on the resolved angle 3 sqrt(d), is nil)
    off, own = np.max(np.abs(vals[trivial] - 1.0)), np.max(np.abs(w[cand] - 1.0))
    if off <= DEFLATION_OFF or off <= own:
        return vals, X, trivial, defect
    direct = np.zeros(k, dtype=bool)
    direct[cand] = True
    return w.astype(complex), Y.astype(complex), direct, defect


def _deflation(
    M: Array, Q: Array
) -> tuple[NDArray[np.complex128], NDArray[np.complex128], NDArray[np.bool_], float]:
    """Eigenpairs of the block ``M`` with its trivial span ``Q`` deflated.

    In an orthonormal basis ``[Q, P]`` (``P`` completing ``Q``), ``M`` is
    block triangular up to the invariance defect ``|Pᵀ M Q|``: the trivial
    multipliers are the eigenvalues of ``Qᵀ M Q`` and the others those of
    ``Pᵀ M P``, however close to 1 they are (the same deflation as
    :func:`floquet_multipliers`). Non-trivial eigenvectors ``P s`` are lifted
    to ``P s + Q z``, ``(μ - QᵀMQ) z = QᵀMP s``, unless ``μ`` sits on a
    trivial value. Returns ``(values, vectors, trivial, defect)``.
    """
    k, r = M.shape[0], Q.shape[1]
    if r == 0:
        w, Y = np.linalg.eig(M)
        return w.astype(complex), Y.astype(complex), np.zeros(k, bool), 0.0
    P = np.linalg.svd(np.eye(k) - Q @ Q.T)[0][:, : k - r]
    R, S = Q.T @ M @ Q, P.T @ M @ P
    tv, tY = np.linalg.eig(R)
    nv, sY = np.linalg.eig(S) if k > r else (np.zeros(0, complex), np.zeros((0, 0), complex))
    Xn = (P @ sY).astype(complex)
    QMP = Q.T @ M @ P
    for j, mu in enumerate(nv):
        A = mu * np.eye(r) - R
        if np.linalg.cond(A) < 1e12:  # else μ sits on a trivial one: keep P s
            Xn[:, j] = Xn[:, j] + Q @ np.linalg.solve(A, QMP @ sY[:, j])
    vals = np.concatenate([tv.astype(complex), nv.astype(complex)])
    X = np.column_stack([(Q @ tY).astype(complex), Xn])
    trivial = np.concatenate([np.ones(r, bool), np.zeros(nv.size, bool)])
    defect = float(np.linalg.norm(P.T @ M @ Q)) if k > r else 0.0
    return vals, X, trivial, defect


def floquet_from_blocks(
    blocks: Sequence[tuple[Array, Array]],
    trivial_directions: Sequence[Array] = (),
    nev: int = 13,
    period: float | None = None,
    labels: Sequence[str] | None = None,
) -> Stability:
    """All Floquet multipliers from dense monodromy blocks (no Arnoldi).

    Parameters
    ----------
    blocks:
        ``(M_b, B_b)`` pairs, ordered so that the monodromy is block upper
        triangular in ``[B_0, B_1, ...]``: ``B_0`` (columns, ``n x k_0``)
        spans an invariant subspace and ``M_0`` is the monodromy there in
        that basis (e.g. the in-plane block of a planar orbit in reduced
        coordinates); a later ``M_b`` is the quotient block in the
        complement ``B_b`` (the out-of-plane block). A single ``(M, I)`` is
        the whole monodromy.
    trivial_directions:
        ``f(u)`` and ``L u`` (full coordinates). Each block gets its share
        of their span (:func:`_block_trivial_spans`) and deflates it
        (:func:`_deflated_block`): the trivial multipliers are those of the
        span, never picked by closeness to 1 or by eigenvector projections.
    nev:
        Number of leading non-trivial pairs whose eigen-residual is reported.
    period:
        If given, ``info["exponents"] = log(μ)/T``.
    labels:
        Optional name per block (e.g. ``("in", "out")`` for a subspace
        solve); ``info["block_label"]`` then names each multiplier's block,
        which classifies its mode exactly (the events read it).

    Returns
    -------
    Stability
        Values sorted leading first, eigenvectors in full coordinates (unit),
        ``residual`` = the largest ``|M_b y - μ y| / |y|`` of the ``nev``
        leading non-trivial pairs (it includes the invariance defect of the
        deflated span), ``info["method"] = "monodromy"``.
    """
    if labels is not None and len(labels) != len(blocks):
        raise ValueError(f"floquet_from_blocks: {len(labels)} labels for {len(blocks)} blocks")
    spans = _block_trivial_spans(blocks, trivial_directions)
    parts = []
    for (M, B), Q in zip(blocks, spans, strict=True):
        M = np.asarray(M, dtype=float)
        w, Y, triv, defect = _deflated_block(M, Q)
        X = np.asarray(B, dtype=float) @ Y
        X = X / np.linalg.norm(X, axis=0, keepdims=True)
        res = np.linalg.norm(M @ Y - Y * w[None, :], axis=0) / np.linalg.norm(Y, axis=0)
        parts.append((w, X, res, triv, defect))
    return stability_from_parts(
        parts, nev, period, labels,
        info={"method": "monodromy",
              "blocks": [int(np.asarray(M).shape[0]) for M, _ in blocks]},
        ranks=[int(Q.shape[1]) for Q in spans])


def stability_from_parts(
    parts: Sequence[tuple[CArray, CArray, Array, Array, float]],
    nev: int,
    period: float | None,
    labels: Sequence[str] | None,
    info: dict[str, Any],
    ranks: Sequence[int],
) -> Stability:
    """One :class:`Stability` from the multipliers of each block.

    ``parts[b] = (values, unit vectors in full coordinates, residuals,
    trivial mask, invariance defect of the trivial span)`` of block ``b``;
    ``info`` holds the method's own entries (``method``, ``blocks``, ...),
    ``ranks`` the trivial span's rank per block. Values are sorted leading
    first; ``residual`` is the largest of the ``nev`` leading non-trivial ones.
    """
    vals = np.concatenate([p[0] for p in parts]).astype(complex)
    X = np.column_stack([p[1] for p in parts]).astype(complex)
    res = np.concatenate([p[2] for p in parts])
    trivial = np.concatenate([p[3] for p in parts])
    blk = np.concatenate([np.full(p[0].size, b) for b, p in enumerate(parts)])
    order = _sort_leading(vals)
    vals, X, res, trivial, blk = vals[order], X[:, order], res[order], trivial[order], blk[order]
    tv = np.concatenate([p[0][p[3]] for p in parts]) if parts else np.zeros(0, complex)
    tinfo = {
        "rank": int(tv.size),
        "method": "deflation",
        "ranks": [int(r) for r in ranks],
        "values": tv,
        "distance_from_one": float(np.max(np.abs(tv - 1.0))) if tv.size else float("nan"),
        # how far each block's trivial span is from invariant (time step, unconverged orbit)
        "invariance_defect": [p[4] for p in parts],
    }
    lead = res[~trivial][: max(int(nev), 0)]
    info = {**info, "block": blk, "iterations": 0, "operator_applications": 0,
            "converged": True, "ritz_change": 0.0, "residuals": res, "trivial_info": tinfo}
    if labels is not None:
        info["block_label"] = np.array([str(labels[int(k)]) for k in blk])
    if period is not None and period > 0:
        with np.errstate(divide="ignore", invalid="ignore"):
            info["exponents"] = np.log(vals) / period
    return Stability(values=vals, kind="multipliers", trivial=trivial, vectors=X,
                     residual=float(np.max(lead)) if lead.size else 0.0, info=info)
