"""Largest Lyapunov exponent by Benettin's method.

Benettin, Galgani, Giorgilli & Strelcyn, Meccanica 15 (1980) 9-20: a tangent
vector ``v`` is carried along the trajectory and renormalised after every step;
the exponent is the running average of the logarithmic growth factors,

    lambda = lim_{n -> inf} (1 / (n dt)) sum_{k=1}^{n} log |v_k'|,   |v_{k-1}| = 1,

where ``v_k'`` is the image of the unit vector ``v_{k-1}``. Renormalising every
step keeps ``v`` finite and makes the sum exact for any run length.

The tangent dynamics come either from a user tangent map ``(u, v) -> (u', Dv)``
(exact linearisation), or from the two-trajectory finite difference of
``step``: a companion state ``u + d v`` (``d`` the stated renormalisation
distance) is stepped along and the difference, divided by ``d``, is the image
of ``v``; the companion is then put back at distance ``d`` along the new
direction.

Memory is O(dim): only the current state, the tangent vector, a running sum,
per-block sums for the error estimate and a decimated history of bounded size.

:class:`LockstepLyapunov` measures the exponent along a trajectory that its
owner steps (a stateful integrator whose trajectory is also classified, say):
a companion system is stepped in lockstep with the reference and put back at
distance ``d`` from it after every map (Benettin), so the exponent covers
exactly the steps the owner took, not a separate copy of the trajectory.
The map's state may be larger than the sampled state (a multistep method's
history): the systems expose it through :class:`LockstepSystem`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from contfil.errors import ContfilError, NonFiniteError, SpecError

__all__ = [
    "LyapunovResult",
    "DecimatedHistory",
    "LockstepSystem",
    "LockstepLyapunov",
    "TangentCarrier",
    "GrowthSums",
    "largest_lyapunov",
]

StepMap = Callable[[NDArray[np.float64]], NDArray[np.float64]]
TangentMap = Callable[
    [NDArray[np.float64], NDArray[np.float64]], tuple[NDArray[np.float64], NDArray[np.float64]]
]


class DecimatedHistory:
    """A bounded record of ``(index, value)`` pairs over an unbounded stream.

    Keeps every ``stride``-th sample; when ``capacity`` is reached, every
    other kept sample is dropped and the stride doubles. The record thus
    always spans the whole run with between capacity/2 and capacity points.
    """

    def __init__(self, capacity: int = 1000) -> None:
        if capacity < 4:
            raise SpecError(f"history capacity must be >= 4, got {capacity}")
        self.capacity = capacity
        self.stride = 1
        self._idx: list[int] = []
        self._val: list[float] = []

    def offer(self, index: int, value: float) -> None:
        """Record ``value`` if ``index`` falls on the current stride."""
        if index % self.stride:
            return
        self._idx.append(index)
        self._val.append(value)
        if len(self._idx) >= self.capacity:
            # Keep the samples that fall on the doubled stride.
            self.stride *= 2
            keep = [i for i, k in enumerate(self._idx) if k % self.stride == 0]
            self._idx = [self._idx[i] for i in keep]
            self._val = [self._val[i] for i in keep]

    def arrays(self) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """The kept indices and values."""
        return np.asarray(self._idx, dtype=np.int64), np.asarray(self._val, dtype=float)


@dataclass(frozen=True)
class LyapunovResult:
    """Largest Lyapunov exponent and its evidence.

    Attributes
    ----------
    exponent:
        Estimate (per unit time: growth logs divided by ``n_steps * dt``).
    error:
        Standard error from the means of ``n_blocks`` consecutive blocks of
        the averaged window (their spread / sqrt(n_blocks)); blocks much longer
        than the correlation time make them near-independent.
    block_means:
        The per-block exponents behind ``error``.
    tail_spread:
        Max - min of the running average over the last half of the run (a
        second, cruder convergence indicator).
    history_steps, history:
        Decimated running average (bounded size) versus step index counted
        from the end of the transient.
    n_steps, transient, dt:
        Averaged steps, discarded steps, time per step.
    method:
        ``"tangent"``, ``"finite_difference"`` or ``"lockstep"``
        (:class:`LockstepLyapunov`; then a step is one map and ``transient``
        the alignment maps).
    fd_distance:
        Renormalisation distance of the two-trajectory method (NaN otherwise).
    """

    exponent: float
    error: float
    block_means: NDArray[np.float64]
    tail_spread: float
    history_steps: NDArray[np.int64]
    history: NDArray[np.float64]
    n_steps: int
    transient: int
    dt: float
    method: str
    fd_distance: float


def _finite(x: NDArray, what: str, k: int) -> NDArray[np.float64]:
    arr = np.asarray(x, dtype=float)
    if not np.all(np.isfinite(arr)):
        raise NonFiniteError(f"largest_lyapunov: {what} is not finite at step {k}")
    return arr


def largest_lyapunov(
    step: StepMap | None,
    u0: ArrayLike,
    n_steps: int,
    dt: float = 1.0,
    *,
    tangent: TangentMap | None = None,
    v0: ArrayLike | None = None,
    transient: int = 0,
    fd_distance: float | None = None,
    n_blocks: int = 10,
    history_size: int = 1000,
    seed: int = 0,
) -> LyapunovResult:
    """Largest Lyapunov exponent of the map ``step`` (one step = time ``dt``).

    Parameters
    ----------
    step:
        ``u -> u_next``. Used for the finite-difference tangent when
        ``tangent`` is None; may be None when ``tangent`` is given.
    u0:
        Initial state (1-D).
    n_steps:
        Steps averaged after the transient.
    dt:
        Time per step (1 for a map).
    tangent:
        ``(u, v) -> (u_next, Dstep(u) v)``, the exact tangent map.
    v0:
        Initial tangent direction (random unit vector from ``seed`` if None).
    transient:
        Steps run first, not averaged: the state settles on the attractor and
        ``v`` aligns with the most unstable direction.
    fd_distance:
        Renormalisation distance ``d`` of the two-trajectory method; default
        ``1e-7 * max(1, |u0|)``: well above round-off (relative error of the
        difference ~ 1e-16 |u| / d ~ 1e-9) yet small enough that the
        linearisation error ~ d |D^2 step| stays below 1e-6 on O(1) attractors.
    n_blocks:
        Blocks of the averaged window for the error estimate (>= 2).
    history_size:
        Bound on the stored running-average history.
    seed:
        Seed of the random initial direction.

    Raises
    ------
    SpecError
        Bad arguments or shapes.
    NonFiniteError
        The state or tangent vector became NaN/inf.
    ContfilError
        The tangent vector collapsed to zero (exponent -inf).
    """
    u = np.array(u0, dtype=float)
    if u.ndim != 1 or u.size == 0:
        raise SpecError(f"largest_lyapunov: u0 must be a non-empty 1-D array, got {u.shape}")
    _finite(u, "u0", 0)
    if step is None and tangent is None:
        raise SpecError("largest_lyapunov: give step or tangent")
    if n_steps < n_blocks or n_blocks < 2:
        raise SpecError(
            f"largest_lyapunov: need n_blocks >= 2 and n_steps >= n_blocks, got "
            f"n_steps={n_steps}, n_blocks={n_blocks}"
        )
    if transient < 0 or not (np.isfinite(dt) and dt > 0):
        raise SpecError(f"largest_lyapunov: need transient >= 0 and dt > 0, got {transient}, {dt}")
    carrier = TangentCarrier(step, u, tangent=tangent, v0=v0, fd_distance=fd_distance,
                             seed=seed)
    for k in range(transient):
        u = carrier.advance(u, k)

    sums = GrowthSums(n_steps, dt, n_blocks, history_size)
    for k in range(1, n_steps + 1):
        u = carrier.advance(u, transient + k)
        sums.add(carrier.log_growth)
    return sums.result(transient, carrier.method, carrier.d)


class TangentCarrier:
    """Benettin's unit tangent vector, carried along a trajectory step by step.

    :meth:`advance` takes the trajectory one step from ``u`` (the state the
    vector is attached to) and returns the next state, with the vector's log
    growth over that step in :attr:`log_growth`. The next state is always
    ``step(u)`` (or the tangent map's image), so an owner that samples the
    returned states classifies the very trajectory the exponent is measured on.

    Parameters
    ----------
    step, tangent, v0, fd_distance, seed:
        As in :func:`largest_lyapunov`; ``u0`` sets the shape and the default
        finite-difference distance ``1e-7 max(1, |u0|)``.
    """

    def __init__(
        self,
        step: StepMap | None,
        u0: NDArray[np.float64],
        *,
        tangent: TangentMap | None = None,
        v0: ArrayLike | None = None,
        fd_distance: float | None = None,
        seed: int = 0,
    ) -> None:
        if step is None and tangent is None:
            raise SpecError("largest_lyapunov: give step or tangent")
        if v0 is None:
            v = np.random.default_rng(seed).standard_normal(u0.size)
        else:
            v = np.array(v0, dtype=float)
            if v.shape != u0.shape:
                raise SpecError(f"largest_lyapunov: v0 shape {v.shape} != u0 shape {u0.shape}")
        nv = np.linalg.norm(v)
        if not (np.isfinite(nv) and nv > 0):
            raise SpecError("largest_lyapunov: v0 must be finite and non-zero")
        self.v = v / nv
        self.step, self.tangent = step, tangent
        if tangent is None:
            d = (1e-7 * max(1.0, float(np.linalg.norm(u0))) if fd_distance is None
                 else fd_distance)
            if not (np.isfinite(d) and d > 0):
                raise SpecError(f"largest_lyapunov: fd_distance must be > 0, got {fd_distance}")
            self.d, self.method = float(d), "finite_difference"
        else:
            self.d, self.method = float("nan"), "tangent"
        self.log_growth = 0.0

    def advance(self, u: NDArray[np.float64], k: int) -> NDArray[np.float64]:
        """The state after ``u`` (step index ``k`` for messages); the unit
        vector moves along and :attr:`log_growth` is its growth's log."""
        if self.tangent is not None:
            un, w = self.tangent(u, self.v)
            un = _finite(un, "state", k)
            w = _finite(w, "tangent vector", k)
        else:
            assert self.step is not None
            un = _finite(self.step(u), "state", k)
            # Two-trajectory difference: the companion sits at u + d v.
            w = (_finite(self.step(u + self.d * self.v), "companion state", k) - un) / self.d
        g = float(np.linalg.norm(w))
        if g == 0.0:
            raise ContfilError(
                f"largest_lyapunov: tangent vector collapsed to zero at step {k} "
                "(exponent is -inf)"
            )
        self.v = w / g
        self.log_growth = float(np.log(g))
        return un


class GrowthSums:
    """Running sum, block sums and decimated running average of log growths."""

    def __init__(self, n_steps: int, dt: float, n_blocks: int, history_size: int) -> None:
        self.n_steps, self.dt, self.n_blocks = int(n_steps), float(dt), int(n_blocks)
        self.block_len = self.n_steps // self.n_blocks
        self.block_sums = np.zeros(self.n_blocks)
        self.hist = DecimatedHistory(history_size)
        self.total = 0.0
        self.k = 0

    def add(self, lg: float) -> None:
        """Count the log growth of the next step."""
        self.k += 1
        self.total += lg
        b = (self.k - 1) // self.block_len
        if b < self.n_blocks:  # remainder steps count in the total only
            self.block_sums[b] += lg
        self.hist.offer(self.k, self.total / (self.k * self.dt))

    def result(self, transient: int, method: str, d: float) -> LyapunovResult:
        """The :class:`LyapunovResult` of the ``n_steps`` steps counted."""
        if self.k != self.n_steps:
            raise ContfilError(f"Lyapunov: {self.k} of {self.n_steps} steps counted")
        exponent = self.total / (self.n_steps * self.dt)
        block_means = self.block_sums / (self.block_len * self.dt)
        error = float(np.std(block_means, ddof=1) / np.sqrt(self.n_blocks))
        hs, hv = self.hist.arrays()
        tail = hv[hs >= self.n_steps // 2]
        spread = float(tail.max() - tail.min()) if tail.size else 0.0
        return LyapunovResult(
            exponent=float(exponent), error=error, block_means=block_means, tail_spread=spread,
            history_steps=hs, history=hv, n_steps=self.n_steps, transient=int(transient),
            dt=self.dt, method=method, fd_distance=float(d),
        )


class LockstepSystem(Protocol):
    """A stateful stepper that :class:`LockstepLyapunov` can drive.

    ``history()`` is the whole state of the discrete map after the steps
    taken (1-D; for a one-step method the state, for a two-step method the
    last two states), the space in which the companion is perturbed and
    renormalised. ``follow(reference, h)`` puts this system at map state
    ``h`` with everything else that the next step depends on (step index,
    solver caches) taken from ``reference``, so that with ``h`` equal to
    ``reference.history()`` the two systems take the same next steps.
    """

    def advance(self, n: int) -> None:
        """Take ``n`` steps (``n >= 1``)."""
        ...

    def history(self) -> NDArray[np.float64]:
        """The state of the discrete map (1-D)."""
        ...

    def follow(self, reference: LockstepSystem, h: NDArray[np.float64]) -> None:
        """Be at map state ``h``, otherwise as ``reference``."""
        ...


class LockstepLyapunov:
    """Largest Lyapunov exponent along a trajectory stepped by its owner.

    The owner calls :meth:`advance` instead of stepping ``reference`` itself:
    ``reference`` and ``companion`` take the same steps, and at every
    ``map_steps``-th step the companion's offset ``w`` from the reference
    (in :meth:`LockstepSystem.history` space) gives the growth ``|w| / d``
    and the companion is put back at ``reference + d w/|w|`` (Benettin with
    a two-trajectory tangent). The first ``skip_maps`` maps align the
    direction and are not averaged; the next ``n_maps`` are, in ``n_blocks``
    blocks for the error, as :func:`largest_lyapunov`. After them the
    companion is no longer stepped (:attr:`done`).

    Parameters
    ----------
    reference, companion:
        Two :class:`LockstepSystem`; the companion is placed at
        ``reference.history() + d v0`` here.
    map_steps:
        Steps per map.
    n_maps:
        Maps averaged (>= n_blocks).
    dt:
        Time per step (a map is ``map_steps dt``).
    skip_maps:
        Maps before the averaged ones (alignment of the direction).
    fd_distance, v0, seed, n_blocks, history_size:
        As in :func:`largest_lyapunov` (``d`` relative to ``|history|``).
    """

    def __init__(
        self,
        reference: LockstepSystem,
        companion: LockstepSystem,
        map_steps: int,
        n_maps: int,
        dt: float,
        *,
        skip_maps: int = 0,
        fd_distance: float | None = None,
        v0: ArrayLike | None = None,
        seed: int = 0,
        n_blocks: int = 10,
        history_size: int = 1000,
    ) -> None:
        if int(map_steps) < 1 or skip_maps < 0:
            raise SpecError(f"LockstepLyapunov: need map_steps >= 1 and skip_maps >= 0, got "
                            f"{map_steps}, {skip_maps}")
        if n_maps < n_blocks or n_blocks < 2:
            raise SpecError(f"LockstepLyapunov: need n_blocks >= 2 and n_maps >= n_blocks, got "
                            f"n_maps={n_maps}, n_blocks={n_blocks}")
        if not (np.isfinite(dt) and dt > 0):
            raise SpecError(f"LockstepLyapunov: dt must be positive and finite, got {dt}")
        self.reference, self.companion = reference, companion
        self.map_steps, self.n_maps, self.skip_maps = int(map_steps), int(n_maps), int(skip_maps)
        h = _finite(reference.history(), "reference state", 0)
        v = (np.random.default_rng(seed).standard_normal(h.size) if v0 is None
             else np.array(v0, dtype=float))
        nv = float(np.linalg.norm(v))
        if v.shape != h.shape or not (np.isfinite(nv) and nv > 0):
            raise SpecError("LockstepLyapunov: v0 must be finite, non-zero, shaped as history()")
        d = 1e-7 * max(1.0, float(np.linalg.norm(h))) if fd_distance is None else fd_distance
        if not (np.isfinite(d) and d > 0):
            raise SpecError(f"LockstepLyapunov: fd_distance must be > 0, got {fd_distance}")
        self.d = float(d)
        self.steps = 0  # steps since the start
        self.maps = 0  # maps completed
        self._sums = GrowthSums(self.n_maps, dt * self.map_steps, n_blocks, history_size)
        companion.follow(reference, h + self.d * v / nv)

    @property
    def done(self) -> bool:
        """All maps taken: the companion is no longer stepped."""
        return self.maps >= self.skip_maps + self.n_maps

    def advance(self, n: int) -> None:
        """Step the reference ``n`` steps (and the companion while maps remain)."""
        n = int(n)
        if n < 0:
            raise SpecError(f"LockstepLyapunov.advance: n must be >= 0, got {n}")
        while n > 0:
            if self.done:
                self.reference.advance(n)
                self.steps += n
                return
            s = min(n, self.map_steps - self.steps % self.map_steps)
            self.reference.advance(s)
            self.companion.advance(s)
            self.steps += s
            n -= s
            if self.steps % self.map_steps == 0:
                self._renormalise()

    def _renormalise(self) -> None:
        self.maps += 1
        h = _finite(self.reference.history(), "reference state", self.steps)
        w = _finite(self.companion.history(), "companion state", self.steps) - h
        g = float(np.linalg.norm(w))
        if g == 0.0:
            raise ContfilError(f"LockstepLyapunov: the companion met the reference at map "
                               f"{self.maps} (exponent is -inf)")
        if self.maps > self.skip_maps:
            self._sums.add(np.log(g / self.d))
        self.companion.follow(self.reference, h + (self.d / g) * w)

    def result(self) -> LyapunovResult:
        """The exponent over the averaged maps (all of them must have been taken)."""
        if not self.done:
            raise ContfilError(f"LockstepLyapunov: {self.maps} of "
                               f"{self.skip_maps + self.n_maps} maps taken")
        return self._sums.result(self.skip_maps, "lockstep", self.d)
