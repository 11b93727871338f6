"""Multipliers of a periodic orbit, read for the cycle events: the
non-trivial ones (trivial ones flagged by their eigenvectors), the part of an
eigenvector off the trivial directions, and whether a mode lies in an
invariant subspace."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from contfil.engine.problems.base import Stability

Array = NDArray[np.float64]


#: ``v`` whose part off the trivial span is below this fraction of ``|v|`` is
#: a trivial direction (round-off level of the projection of a unit vector).
OFF_TRIVIAL_FLOOR = 1e-13
#: A complex pair is resolved from +1 (may be a torus) when ``|arg μ|`` exceeds
#: this many times ``√δ``, ``δ`` the trivial multipliers' distance from 1
#: (:func:`resolved_angle`): "well above", since the coupling that splits a
#: double multiplier into ``1 ± i√(cδ)`` has an unknown factor ``c``.
RESOLVED_ANGLE_FACTOR = 3.0
#: A mode whose eigenvector is this close to the trivial span cannot be
#: placed in or out of an invariant subspace (see :func:`subspace_class`).
UNCLASSIFIABLE = 1e-8


def _nontrivial(st: Stability) -> tuple[NDArray[np.complex128], NDArray[np.intp]]:
    vals = np.asarray(st.values, dtype=complex)
    idx = np.arange(vals.size)
    if st.trivial is not None:
        idx = idx[~np.asarray(st.trivial, dtype=bool)]
    return vals[idx], idx


def _log_nearest_circle(c: NDArray) -> float:
    """``log|μ|`` of the multiplier nearest the unit circle, multiplicatively
    (``|μ| - 1`` would prefer 1e-3 over 2 and lose the crossing one); NaN if
    there is none."""
    if c.size == 0:
        return float("nan")
    with np.errstate(divide="ignore"):
        lg = np.log(np.abs(c))
    return float(lg[int(np.argmin(np.abs(lg)))])


def n_outside(c: NDArray) -> int:
    """Number of multipliers ``c`` outside the unit circle."""
    return int(np.sum(np.abs(c) > 1.0))


def _log_ordered(c: NDArray, m: int) -> float:
    """``log|μ|`` of the ``m``-th largest modulus of ``c`` (0-based); NaN if
    there are not that many.

    Localising a crossing of the unit circle between two points where ``m``
    and more than ``m`` multipliers lie outside it: this one is inside at the
    first and outside at the second, so the test changes sign whatever the
    other multipliers do, and the ordered moduli are continuous along the
    branch. The multiplier nearest the circle is not enough: a pair jumping
    from 0.67 to 3.4 in one step while another sits at 0.3 is nearest at
    neither end (tip SF's buckled-beating at b1 = 3727.5)."""
    if c.size <= m:
        return float("nan")
    mod = np.sort(np.abs(c))[::-1]
    with np.errstate(divide="ignore"):
        return float(np.log(mod[m]))


def crossing_localiser(candidates: Callable[[Any], NDArray], ctx0: Any,
                       ctx1: Any) -> Callable[[Any], float]:
    """A test function for the crossing of the unit circle between ``ctx0``
    and ``ctx1`` by one of ``candidates(ctx)``: :func:`_log_ordered` at the
    smaller of the two ends' counts outside the circle."""
    m = min(n_outside(candidates(ctx0)), n_outside(candidates(ctx1)))
    return lambda ctx: _log_ordered(candidates(ctx), m)


def _is_real(z: NDArray[np.complex128], tol: float) -> NDArray[np.bool_]:
    return np.abs(z.imag) <= tol * np.maximum(1.0, np.abs(z))


def _critical_vector(st: Stability, target: complex) -> dict[str, Any]:
    """The non-trivial multiplier closest to ``target`` and its eigenvector."""
    vals, idx = _nontrivial(st)
    if vals.size == 0:
        return {}
    k = int(np.argmin(np.abs(vals - target)))
    out: dict[str, Any] = {"multiplier": complex(vals[k])}
    if st.vectors is not None:
        v = np.asarray(st.vectors[:, idx[k]], dtype=complex)
        # real eigenvector for a real multiplier: rotate the phase away
        j = int(np.argmax(np.abs(v)))
        v = v * np.exp(-1j * np.angle(v[j]))
        out["v_re"], out["v_im"] = v.real.copy(), v.imag.copy()
    return out


def trivial_accuracy(st: Stability) -> float:
    """How far the trivial multipliers of ``st`` are from 1: the measured
    accuracy of the multipliers near +1 (0 if not known).

    Read from the Floquet solvers' record (``info["trivial_info"]
    ["distance_from_one"]`` of shooting, ``info["trivial_distance"]`` of
    collocation), else from the flagged values themselves.
    """
    info = st.info or {}
    d = info.get("trivial_distance")
    if d is None:
        d = (info.get("trivial_info") or {}).get("distance_from_one")
    if d is None and st.trivial is not None and np.any(st.trivial):
        vals = np.asarray(st.values, dtype=complex)[np.asarray(st.trivial, dtype=bool)]
        d = float(np.max(np.abs(vals - 1.0)))
    d = float(d) if d is not None else 0.0
    return d if np.isfinite(d) else 0.0


def resolved_angle(st: Stability) -> float:
    """Smallest ``|arg μ|`` at which a complex pair of ``st`` is resolved from +1.

    A real multiplier near +1 next to the trivial ones (at a fold or branch
    point of cycles: a double multiplier at 1 with a Jordan block) is split
    by an error ``δ`` of the monodromy into ``1 ± √δ`` or ``1 ± i√δ``
    (Puiseux: the eigenvalues of ``[[1, 1], [-δ, 1]]`` are ``1 ± i√δ``).
    ``δ`` is measured by the trivial multipliers' distance from 1
    (:func:`trivial_accuracy`), so a pair whose angle is below ``√δ`` is
    not resolved from the 1:1 resonance: it is no torus (the fold or branch
    point is its own event). Returns ``RESOLVED_ANGLE_FACTOR · √δ``.

    Tip SF's QP1 reported "tori" at pairs ``1 ± 7e-4 i`` next to its fold
    of cycles; the trivial multipliers of the filament's relative periodic
    orbits sit ~1e-5 from 1 (tip FF's QP1), so ``√δ ≈ 3e-3``.
    """
    d = trivial_accuracy(st)
    return RESOLVED_ANGLE_FACTOR * float(np.sqrt(d)) if d > 0.0 else 0.0


def _trivial_basis(st: Stability) -> Array | None:
    """Orthonormal real basis of the span of the trivial eigenvectors of ``st``."""
    if st.trivial is None or st.vectors is None or not np.any(st.trivial):
        return None
    E = np.asarray(st.vectors)[:, np.asarray(st.trivial, dtype=bool)]
    E = np.column_stack([E.real, E.imag])
    U, sv, _ = np.linalg.svd(E, full_matrices=False)
    if sv.size == 0 or sv[0] == 0.0:
        return None
    return U[:, : int(np.sum(sv > 1e-8 * sv[0]))]


def off_trivial(st: Stability, v: NDArray) -> NDArray:
    """``v`` without its part along the trivial eigenvectors of ``st``.

    Why: near ``μ = 1`` the eigenvector of a multiplier crossing +1 is
    polluted by the trivial directions. With ``M v = μ v + c e`` (``e`` =
    ``f(u)`` or ``L u``, multiplier 1) the exact eigenvector is
    ``v + c e / (μ - 1)``: it tends to ``e`` at the crossing. When ``e``
    lies in an invariant subspace (``f`` of a planar orbit) an out-of-plane
    mode then looks in-plane (``subspace_fraction`` 0.29-0.39 on the tip FF
    beating pitchfork, and crossings went unreported). The bifurcating
    direction is the part orthogonal to the trivial span; it is returned
    unless ``v`` lies inside that span to round-off. (Right at the crossing
    that part is only ``~|μ - 1|/c`` of ``v``, still far above round-off at
    any ``|μ - 1|`` a localisation reaches; the deflated Floquet solver keeps
    the compressed eigenvector, already free of the trivial part, when
    ``μ`` is within round-off of a trivial multiplier.)
    """
    Q = _trivial_basis(st)
    if Q is None:
        return v
    w = v - Q @ (Q.T @ v)
    if np.linalg.norm(w) <= OFF_TRIVIAL_FLOOR * np.linalg.norm(v):
        return v
    return w


def subspace_class(subspace: Any, st: Stability, k: int, threshold: float = 0.5) -> str:
    """``"in"``, ``"out"`` or ``"unknown"``: where mode ``k`` of ``st`` lives.

    Classified on the eigenvector without its trivial part
    (:func:`off_trivial`): ``"out"`` when less than ``threshold`` of it lies
    in ``subspace``. ``"unknown"`` when that part is below
    ``UNCLASSIFIABLE`` of the eigenvector: the multiplier is then within
    round-off of a trivial one (a localisation iterate right at the
    crossing) and the vector no longer says where the mode lives; both the
    in-subspace and the subspace-breaking tests keep such a mode as a
    candidate, so neither loses the crossing it is localising.

    Multipliers computed block by block (``info["block_label"]`` of
    :func:`~contfil.engine.linalg.floquet.floquet_from_blocks`: the in-subspace
    block and the block normal to it) are classified by their block, exactly:
    there the eigenvector is not needed, and a multiplier crossing +1 next to
    a trivial one is still placed.
    """
    lab = st.info.get("block_label") if st.info else None
    if lab is not None and len(lab) == len(st.values) and str(lab[k]) in ("in", "out"):
        return str(lab[k])
    if st.vectors is None:
        return "unknown"
    v = np.asarray(st.vectors[:, k])
    w = off_trivial(st, v)
    if w is v and st.trivial is not None and np.any(st.trivial):
        return "unknown"
    if np.linalg.norm(w) <= UNCLASSIFIABLE * np.linalg.norm(v):
        return "unknown"
    return "out" if subspace_fraction(subspace, w) < threshold else "in"


def subspace_fraction(subspace: Any, v: NDArray) -> float:
    """Fraction ``|P v| / |v|`` of a (complex) full-model vector in ``subspace``.

    ``P = embed ∘ project`` is the orthogonal projector onto a coordinate
    subspace (the filament's plane: one of three components per segment);
    it is applied to the real and imaginary parts separately because
    models' ``embed`` need not accept complex arrays.
    """
    v = np.asarray(v)
    nv = float(np.linalg.norm(v))
    if nv == 0.0:
        return float("nan")

    def P(w: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.asarray(subspace.embed(subspace.project(w)), dtype=float)

    pv = np.hypot(np.linalg.norm(P(v.real)), np.linalg.norm(P(np.imag(v)))) \
        if np.iscomplexobj(v) else np.linalg.norm(P(v))
    return float(pv / nv)
