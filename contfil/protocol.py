"""The plug-in contract between the engine and a model.

The engine only ever calls the members listed in :class:`Model`. A model is
any object that provides them (structural typing); :class:`FunctionModel`
turns a plain Python function ``f(u, p)`` into one.

Conventions
-----------
- ``u`` is a 1-D float array of length ``model.dim``.
- ``p`` is a 1-D float array of length ``len(model.param_names)``; the engine
  continues one entry of it, named by the user.
- Continuous symmetries are one-parameter groups ``g(theta) = expm(theta*L)``
  acting linearly on ``u``; ``L`` is the generator (a ``dim x dim`` array).
- ``flow(u, p, T)`` must be a smooth function of ``u`` and ``T`` (a fixed
  number of steps per call, not adaptive), because the engine differentiates
  it by finite differences for shooting and Floquet multipliers.
- ``flow_tangent(u, p, T, V, param_index, samples)`` (optional) returns the
  exact derivative of that same discrete flow as a :class:`FlowTangent`:
  ``Dphi_T(u) V`` for the columns of ``V`` (``None``: the identity, i.e.
  the monodromy), ``dphi/dT`` and ``dphi/dp[param_index]`` from one sweep.
  The engine probes it once (:func:`flow_tangent_hook`) and then uses it for
  shooting Jacobians, tangents and Floquet multipliers instead of finite
  differences.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


@dataclass(frozen=True)
class ContinuousSymmetry:
    """A one-parameter symmetry group ``u -> expm(theta * generator) @ u``.

    Parameters
    ----------
    name:
        Human-readable name, e.g. ``"rotation_e3"``.
    generator:
        The ``dim x dim`` generator ``L``; the model's vector field commutes
        with it: ``f(expm(theta L) u) = expm(theta L) f(u)``.
    period:
        Group period in ``theta`` (``2*pi`` for a rotation), or ``None``.
    """

    name: str
    generator: Array
    period: float | None = 2 * np.pi

    def act(self, theta: float, u: Array) -> Array:
        """Apply the group element of angle ``theta`` to ``u``."""
        from scipy.linalg import expm

        return expm(theta * self.generator) @ u

    def tangent(self, u: Array) -> Array:
        """The infinitesimal action ``L u`` (the symmetry direction at ``u``)."""
        return self.generator @ u


@dataclass(frozen=True)
class InvariantSubspace:
    """A linear invariant subspace with a cheaper reduced model living on it.

    ``embed`` maps a reduced state to the full one, ``project`` the reverse
    (exact on the subspace). ``reduced_model`` is a full :class:`Model` whose
    states are the reduced coordinates.
    """

    name: str
    embed: Callable[[Array], Array]
    project: Callable[[Array], Array]
    reduced_model: Callable[[], Model]


@dataclass
class FlowTangent:
    """Result of a model's ``flow_tangent`` hook (one sweep along the flow).

    ``phi`` is ``phi_T(u)``; ``jvp`` (dim, k) is ``Dphi_T(u) V``; ``dT`` and
    ``dp`` are ``dphi/dT`` and ``dphi/dp[param_index]`` (``None`` when not
    asked for); ``samples`` (k, dim), if asked for, the states at ``t = j
    T/k``, j = 0..k-1 (period means without extra flows).
    """

    phi: Array
    jvp: Array
    dT: Array | None = None
    dp: Array | None = None
    samples: Array | None = None


#: The optional hook ``flow_tangent(u, p, T, V, param_index, samples) -> FlowTangent``.
FlowTangentFn = Callable[..., FlowTangent]


def flow_tangent_hook(model: Any) -> FlowTangentFn | None:
    """The model's ``flow_tangent`` hook, or ``None`` (the default: no exact
    tangents). A model may offer the hook but keep it off with
    ``exact_tangents = False``. Probe it once per model, never in a loop."""
    if getattr(model, "exact_tangents", True) is False:
        return None
    fn = getattr(model, "flow_tangent", None)
    return fn if callable(fn) else None


@dataclass
class Symmetries:
    """Symmetries a model declares; all optional."""

    continuous: list[ContinuousSymmetry] = field(default_factory=list)
    reflections: dict[str, Array] = field(default_factory=dict)
    invariant_subspaces: dict[str, InvariantSubspace] = field(default_factory=dict)


@runtime_checkable
class Model(Protocol):
    """What the engine needs from a model.

    Required: ``name``, ``dim``, ``param_names``, ``default_params``,
    ``initial_state``, ``rhs``, ``symmetries``, ``observables``.
    Optional (checked with ``getattr``): ``jacobian(u, p)`` returning a dense
    array, ``flow(u, p, T)`` a time-stepper, ``flow_jvp(u, p, T, v)``,
    ``flow_tangent(u, p, T, V, param_index, samples)`` the exact tangent of
    ``flow`` (see :class:`FlowTangent`; probed by :func:`flow_tangent_hook`).
    """

    name: str
    dim: int
    param_names: tuple[str, ...]
    symmetries: Symmetries

    def default_params(self) -> Array: ...

    def initial_state(self, p: Array) -> Array: ...

    def rhs(self, u: Array, p: Array) -> Array: ...

    def observables(self, u: Array, p: Array) -> Mapping[str, Any]: ...


class FunctionModel:
    """Wrap a plain function ``f(u, p) -> du/dt`` as a :class:`Model`.

    Parameters
    ----------
    f:
        The vector field; ``u`` and ``p`` are float arrays.
    dim:
        State dimension.
    params:
        Parameter names and default values, in the order ``p`` is indexed.
    jacobian:
        Optional dense Jacobian ``J(u, p)``; finite differences otherwise.
    u0:
        Optional initial state (zeros otherwise).
    symmetries:
        Optional declared symmetries.
    observables:
        Optional ``obs(u, p) -> dict``; by default ``{"norm": |u|, "u0": u[0]}``.

    Examples
    --------
    >>> m = FunctionModel(lambda u, p: p[0] * u - u**3, dim=1, params={"mu": -1.0})
    >>> m.rhs(np.array([1.0]), m.default_params())
    array([-2.])
    """

    def __init__(
        self,
        f: Callable[[Array, Array], Array],
        dim: int,
        params: Mapping[str, float],
        *,
        name: str = "function_model",
        jacobian: Callable[[Array, Array], Array] | None = None,
        u0: Array | None = None,
        symmetries: Symmetries | None = None,
        observables: Callable[[Array, Array], Mapping[str, Any]] | None = None,
    ) -> None:
        if dim <= 0:
            raise ValueError(f"FunctionModel: dim must be a positive integer, got {dim!r}")
        self.name = name
        self.dim = int(dim)
        self.param_names = tuple(params)
        self._defaults = np.array([float(params[k]) for k in self.param_names], dtype=float)
        self._f = f
        self._u0 = np.zeros(self.dim) if u0 is None else np.asarray(u0, dtype=float).copy()
        if self._u0.shape != (self.dim,):
            raise ValueError(
                f"FunctionModel: u0 has shape {self._u0.shape}, expected ({self.dim},)"
            )
        self.symmetries = symmetries or Symmetries()
        self._obs = observables
        if jacobian is not None:
            self.jacobian = lambda u, p: np.asarray(jacobian(u, p), dtype=float)

    def default_params(self) -> Array:
        return self._defaults.copy()

    def initial_state(self, p: Array) -> Array:
        return self._u0.copy()

    def rhs(self, u: Array, p: Array) -> Array:
        return np.asarray(self._f(u, p), dtype=float)

    def observables(self, u: Array, p: Array) -> Mapping[str, Any]:
        if self._obs is not None:
            return dict(self._obs(u, p))
        return {"norm": float(np.linalg.norm(u)), "u0": float(u[0])}


def param_index(model: Model, name: str) -> int:
    """Index of parameter ``name`` in ``model.param_names``, with a clear error."""
    try:
        return model.param_names.index(name)
    except ValueError:
        raise KeyError(
            f"model {model.name!r} has no parameter {name!r}; known: {list(model.param_names)}"
        ) from None
