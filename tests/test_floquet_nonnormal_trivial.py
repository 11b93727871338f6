"""Trivial multipliers of a strongly non-normal monodromy block.

The trivial span (``f(u)``, ``L u``) comes from the continuous model, so a
discrete monodromy leaves it invariant only up to the time step. With a
large multiplier ``λ`` a direction error ``δ`` becomes a defect ``~ λ δ``
and the deflated trivial value drifts far from 1 (dis FF's unstable beating
in Radau: 7.5 and 1.14–1.19, hiding a torus as a stability change). The
block's own eigenvector is then the trivial one; next to a Jordan pair
(a genuine multiplier at 1) the deflation stays.
"""

from __future__ import annotations

import numpy as np
import pytest

from contfil.engine.linalg.floquet import _deflated_block, _deflation, floquet_from_blocks


def _block(values: list[float], seed: int = 3, skew: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """``V diag(values) V⁻¹`` with columns of ``V`` leaning towards the first (``skew``)."""
    rng = np.random.default_rng(seed)
    k = len(values)
    V = rng.standard_normal((k, k))
    V[:, 1:] += skew * V[:, :1]
    V /= np.linalg.norm(V, axis=0)
    return V @ np.diag(values) @ np.linalg.inv(V), V


@pytest.mark.parametrize("delta", [1e-3, 4e-3])
def test_an_inexact_trivial_direction_next_to_a_large_multiplier(delta: float) -> None:
    values = [1.0, 400.0, 0.5, 0.3, -0.2, 0.1]
    M, V = _block(values, skew=3.0)  # non-normal: the leading eigenvectors lean together
    err = V[:, 1] - (V[:, 1] @ V[:, 0]) * V[:, 0]
    q = V[:, 0] + delta * err / np.linalg.norm(err)
    Q = (q / np.linalg.norm(q))[:, None]
    old, _, old_triv, _ = _deflation(M, Q)
    assert abs(old[old_triv][0] - 1.0) > 0.05  # the deflation's value is far off
    w, Y, triv, defect = _deflated_block(M, Q)
    assert defect > 0.1
    # eig's own accuracy on this ill-conditioned V (cond ~1e2) is ~1e-10
    assert triv.sum() == 1 and abs(w[triv][0] - 1.0) < 1e-8
    assert np.allclose(np.sort(w[~triv].real), np.sort(values[1:]), rtol=1e-8, atol=1e-10)
    assert np.allclose(M @ Y, Y * w[None, :], atol=1e-8 * np.linalg.norm(M))


def test_a_jordan_pair_at_one_keeps_the_deflation() -> None:
    """A genuine multiplier 1 + ε next to the trivial 1 with nearly parallel
    eigenvectors: both sit near the span, no eigenvector is singled out, and
    the trivial value is the deflated one (1 to the defect)."""
    k = 5
    rng = np.random.default_rng(1)
    V = np.linalg.qr(rng.standard_normal((k, k)))[0]
    J = np.diag([1.0, 1.0 + 1e-8, 0.4, 0.2, -0.3])
    J[0, 1] = 1.0  # Jordan-like coupling: eigenvectors 1e-8 apart
    M = V @ J @ V.T
    Q = V[:, :1]
    w, _, triv, _ = _deflated_block(M, Q)
    ref, _, rtriv, _ = _deflation(M, Q)
    assert np.array_equal(np.sort_complex(w), np.sort_complex(ref))
    assert abs(w[triv][0] - 1.0) < 1e-12 and np.array_equal(triv.sum(), rtriv.sum())


@pytest.mark.parametrize("delta", [1e-6, 1e-2])
def test_a_pair_split_at_one_keeps_the_deflation(delta: float) -> None:
    """A double multiplier 1 split by an error into ``1 ± i√δ``: its two
    eigenvectors lie at equal angles on either side of an inexact trivial
    direction, none is singled out, and the deflation stays (its value is
    off by the direction error, as before)."""
    k = 5
    rng = np.random.default_rng(2)
    V = np.linalg.qr(rng.standard_normal((k, k)))[0]
    J = np.diag([1.0, 1.0, 0.4, 0.2, -0.3])
    J[0, 1], J[1, 0] = 1.0, -delta
    M = V @ J @ V.T
    Q = (V[:, :1] + 1e-3 * V[:, 2:3]) / np.hypot(1.0, 1e-3)
    w, _, triv, _ = _deflated_block(M, Q)
    ref, _, rtriv, _ = _deflation(M, Q)
    assert np.array_equal(np.sort_complex(w), np.sort_complex(ref))
    assert np.array_equal(triv.sum(), rtriv.sum())


def test_an_exact_span_is_unchanged() -> None:
    """With an invariant trivial span the result is the deflation's to rounding."""
    values = [1.0, 30.0, 0.5, 0.25]
    M, V = _block(values, seed=7)
    st = floquet_from_blocks([(M, np.eye(4))], [V[:, 0]])
    tv = st.values[np.asarray(st.trivial, bool)]
    assert tv.size == 1 and abs(tv[0] - 1.0) < 1e-12
    assert np.allclose(np.sort(st.values[~np.asarray(st.trivial, bool)].real), [0.25, 0.5, 30.0])
