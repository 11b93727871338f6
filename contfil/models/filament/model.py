"""The active-filament model as a :class:`contfil.protocol.Model`.

State: the effective Lie-algebra elements ``U_n`` (n = 2..N) flattened
segment-major (3D, ``dim = 3(N-1)``), or the in-plane tangent angles
``phi_n`` with ``U_n = (0, phi_n, 0)`` (planar, ``dim = N-1``, motion in the
x-z plane). ``rhs`` solves the linear constraint system for the internal
forces and clamp reactions at the current configuration and returns
``dU_n/dt = dexp_inv(U_n, Omega_n)``. See docs/filament-model.md.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from contfil.errors import NonFiniteError, SpecError
from contfil.protocol import (
    ContinuousSymmetry,
    InvariantSubspace,
    Symmetries,
)

from .integrators import DT_MAX, STEPS_PER_PERIOD, default_steps
from .kernels import constraints as _kc
from .kernels import geometry as _geo
from .physics import FilamentPhysics, bending_energy, embed_planar, frame_observables
from .scene import Scene, load_scene

Array = np.ndarray

#: Time steppers a model can use (``FilamentModel(..., integrator=...)``).
INTEGRATORS = ("bdf2", "radau")


def _rz_generator(nseg: int) -> Array:
    G = np.zeros((3 * nseg, 3 * nseg))
    for n in range(nseg):
        G[3 * n + 1, 3 * n] = 1.0
        G[3 * n, 3 * n + 1] = -1.0
    return G


class FilamentModel:
    """Clamped active filament assembled from a :class:`Scene`.

    Parameters
    ----------
    scene:
        A :class:`Scene`, a ``[scene]`` table (dict) or a TOML file path.

    Notes
    -----
    ``p = [s]`` holds the actuation strength (``f`` or ``b1``); a passive
    scene has no parameters; a two-actuation scene (``"follower_force+squirmer"``)
    has two, ``p = [f, b1]``. Units: L = 1, K_B and eta as in the scene.
    """

    #: Exact tangents of the flow (``flow_tangent``) for the engine's shooting
    #: problems: Newton Jacobians, tangents, Floquet multipliers (in-plane
    #: and out-of-plane blocks) and period means from one tangent sweep
    #: (docs/paper-studies.md, "Rerun with exact tangents"). A model may set
    #: it False to make the engine use finite differences of the flow.
    exact_tangents: bool = True

    def __init__(self, scene: Scene | Mapping[str, Any] | str | Path,
                 integrator: str = "bdf2", steps_per_period: int | None = None) -> None:
        if not isinstance(scene, Scene):
            scene = load_scene(scene)
        if integrator not in INTEGRATORS:
            raise ValueError(f"FilamentModel: integrator must be one of {INTEGRATORS}, "
                             f"got {integrator!r}")
        #: the time stepper of ``flow`` and ``flow_tangent``: ``"bdf2"`` (the
        #: paper's, default) or ``"radau"`` (Radau IIA, order 5; see
        #: :mod:`.integrators.radau`)
        self.integrator = integrator
        if integrator == "radau":
            from .integrators.radau import RADAU_STEPS_PER_PERIOD

            # the periodic-orbit problems shoot at this resolution (the
            # switchers read it): 80 Radau steps give a period error ~1e-8
            # for the cost of BDF2 at T/400 (docs/accuracy.md)
            self.flow_steps_min = RADAU_STEPS_PER_PERIOD
        if steps_per_period is not None:
            if int(steps_per_period) < 4:
                raise ValueError("FilamentModel: steps_per_period must be >= 4, "
                                 f"got {steps_per_period!r}")
            self.flow_steps_min = int(steps_per_period)
        self.scene = scene
        self.N = scene.N
        self.dL = scene.dL
        self.planar = scene.planar
        self.name = scene.name + ("_planar" if self.planar and "planar" not in scene.name else "")
        self.dim = (scene.N - 1) if self.planar else 3 * (scene.N - 1)
        self.param_names: tuple[str, ...] = scene.param_names
        self._defaults = np.array(scene.strengths, dtype=float)
        #: the one physics object: rhs, the integrators and the observables use it
        self.physics = FilamentPhysics(scene)
        self.symmetries = self._build_symmetries()
        self.flow = self._flow

    # -- protocol ---------------------------------------------------------
    def default_params(self) -> Array:
        return self._defaults.copy()

    def initial_state(self, p: Array | None = None) -> Array:
        """The upright filament (all ``U_n = 0``)."""
        return np.zeros(self.dim)

    def rhs(self, u: Array, p: Array) -> Array:
        """The vector field ``du/dt``."""
        return self.evaluate(u, p)[0]

    def evaluate(self, u: Array, p: Array) -> tuple[Array, Array, Array]:
        """``(du/dt, lam, vel)``: the vector field, the multipliers and velocities.

        3D: ``lam = [Lam_{3/2}..Lam_{N-1/2} (3 each), Fc, Tc]`` and ``vel =
        [V_1..V_N, Omega_1..Omega_N]``. Planar: ``lam = [Lam_x, Lam_z per joint,
        Fc_x, Fc_z, Tc_y]``, ``vel = [V_x, V_z per segment, Omega_y ...]``.
        """
        u = np.asarray(u, dtype=np.float64)
        if u.shape != (self.dim,):
            raise ValueError(f"{self.name}: state has shape {u.shape}, expected ({self.dim},)")
        if not np.isfinite(u).all():
            raise NonFiniteError(f"{self.name}.rhs: non-finite state (NaN/inf in u)")
        par = self.physics.params_cached(self._strength(p))
        out = self.physics.evaluate(u, par)
        if not np.isfinite(out[0]).all():
            raise NonFiniteError(
                f"{self.name}.rhs: non-finite vector field at |u|={np.linalg.norm(u):.3g}"
            )
        return out

    def _strength(self, p: Array) -> Any:
        """The physics' strength of the parameter vector ``p``: a number (one
        actuation; 0 for a passive scene) or the pair ``(f, b1)``."""
        n = len(self.param_names)
        if n == 0:
            return 0.0
        if n == 1:
            return float(p[0])
        if len(p) != n:
            raise ValueError(f"{self.name}: parameter vector has {len(p)} entries, expected "
                             f"{n} {list(self.param_names)}")
        return tuple(float(v) for v in p)

    def jacobian(self, u: Array, p: Array) -> Array:
        """Dense Jacobian of :meth:`rhs` by central differences (O(h^2))."""
        u = np.asarray(u, dtype=np.float64)
        J = np.empty((self.dim, self.dim))
        h0 = np.finfo(float).eps ** (1.0 / 3.0)
        up = u.copy()
        for i in range(self.dim):
            h = h0 * max(1.0, abs(u[i]))
            up[i] = u[i] + h
            fp = self.rhs(up, p)
            up[i] = u[i] - h
            fm = self.rhs(up, p)
            up[i] = u[i]
            J[:, i] = (fp - fm) / (2.0 * h)
        return J

    #: Resolution of ``flow`` when neither ``steps`` nor ``dt`` is given (read
    #: by the explorer): :func:`~contfil.models.filament.integrators.default_steps`,
    #: max(STEPS_PER_PERIOD, ceil(T/DT_MAX)).
    flow_steps_min: int = STEPS_PER_PERIOD
    flow_dt_max: float = DT_MAX

    def flow_steps(self, T: float) -> int:
        """Steps of a flow over time ``T`` when none are given:
        ``flow_steps_min`` per period (400 for BDF2, 80 for Radau, or the
        spec's ``[integrator] steps_per_period``), refined on long horizons
        so that no step exceeds the stepper's ``DT_MAX`` scaled alike."""
        n = int(self.flow_steps_min)
        return max(n, default_steps(T) * n // STEPS_PER_PERIOD)

    def _flow(
        self, u: Array, p: Array, T: float, steps: int | None = None, dt: float | None = None,
        **stepper_kw: Any,
    ) -> Array:
        """Time-T map by BDF2 (:func:`contfil.models.filament.integrators.bdf2.flow`)
        or, with ``integrator="radau"``, by :func:`.integrators.radau.flow`.

        ``steps`` or ``dt`` set the resolution; neither: ``default_steps(T)``.
        ``stepper_kw`` go to the stepper (``jacobian``, ``tol``, ...); an
        unknown keyword raises ``TypeError`` there, never silently ignored.
        """
        if self.integrator == "radau":
            from .integrators import radau

            if steps is None and dt is None:
                steps = self.flow_steps(T)
            return radau.flow(self, u, p, T, steps=steps, dt=dt, **stepper_kw)
        from .integrators import bdf2 as stepper

        if steps is None and dt is None:
            steps = self.flow_steps(T)
        return stepper.flow(self, u, p, T, steps=steps, dt=dt, **stepper_kw)

    def flow_tangent(
        self, u: Array, p: Array, T: float, V: Array | None = None,
        param_index: int | None = None, samples: int = 0, steps: int | None = None,
        **stepper_kw: Any,
    ) -> Any:
        """Exact tangent of :meth:`flow` (the protocol's optional hook):
        :func:`contfil.models.filament.integrators.bdf2_tangent.flow_tangent`
        (or the Radau one) with ``dphi/dp_i`` when ``param_index = i`` is given
        (the derivative in the model's parameter ``param_names[i]``)."""
        if self.integrator == "radau":
            from .integrators import radau

            n = self.flow_steps(T) if steps is None else int(steps)
            k = samples if samples and n % samples == 0 else 0
            return radau.flow_tangent(self, u, p, T, V, steps=n,
                                      want_p=param_index is not None, samples=k,
                                      param_index=param_index, **stepper_kw)
        from .integrators.bdf2_tangent import flow_tangent

        n = self.flow_steps(T) if steps is None else int(steps)
        k = samples if samples and n % samples == 0 else 0
        return flow_tangent(self, u, p, T, V, steps=n, want_p=param_index is not None,
                            samples=k, param_index=param_index, **stepper_kw)

    #: Scene fields a stored run's filament must share with this model's for
    #: its states to be this model's (everything but the actuation strengths
    #: and types, and the name).
    STORED_SCENE_FIELDS = ("N", "dL_over_a", "dimension", "KB", "KT", "hydrodynamics",
                           "eta", "profile", "base")

    def stored_params(self, spec: Mapping[str, Any], param: str, values: Array) -> Array:
        """This model's parameter vector for a point stored by a run of spec
        ``spec`` (its manifest's), continued in ``param`` with parameters
        ``values`` (:func:`contfil.explore.start.stored_start`, when a study
        continues a stored point in another parameter or with another number
        of parameters).

        The stored scene must be this filament (:data:`STORED_SCENE_FIELDS`
        equal); each stored parameter value goes to this model's parameter
        of the same name, the others keep this model's (spec's) values. So a
        tip SF point at ``b1`` started in a ``"follower_force+squirmer"``
        scene with ``f = 0`` is the same orbit. A mismatch raises a one-line
        :class:`SpecError` naming it.
        """
        table = spec.get("scene") if isinstance(spec, Mapping) else None
        if not isinstance(table, Mapping):
            raise SpecError("start.run: the stored run has no [scene] table; its parameters "
                            f"cannot be mapped onto scene {self.scene.name!r}")
        try:
            stored = Scene.from_dict(table)
        except SpecError as exc:
            raise SpecError(f"start.run: the stored run's scene: {exc}") from None
        for key in self.STORED_SCENE_FIELDS:
            a, b = getattr(stored, key), getattr(self.scene, key)
            if a != b:
                raise SpecError(f"start.run: the stored run's scene has {key} = {a!r}, this "
                                f"spec's {b!r}: not the same filament")
        names = stored.param_names
        values = np.atleast_1d(np.asarray(values, dtype=float))
        if values.size != len(names):
            raise SpecError(f"start.branch: the stored points have {values.size} parameter(s), "
                            f"the stored scene {list(names)}")
        if param not in names:
            raise SpecError(f"start.branch: the stored branch is continued in {param!r}, not a "
                            f"parameter of the stored scene {list(names)}")
        p = self.default_params()
        for name, v in zip(names, values, strict=True):
            if name not in self.param_names:
                raise SpecError(f"start.branch: the stored parameter {name!r} is not one of "
                                f"model {self.name!r}'s {list(self.param_names)}")
            p[self.param_names.index(name)] = float(v)
        return p

    # -- geometry helpers -------------------------------------------------
    def full_state(self, u: Array) -> Array:
        """The 3D state ``U`` (planar states are embedded as ``U_n = (0, phi_n, 0)``)."""
        u = np.asarray(u, dtype=float)
        return embed_planar(u) if self.planar else u

    def tangents(self, u: Array) -> Array:
        """Unit tangents (N, 3)."""
        if self.planar:
            t2, _ = _kc.planar_configuration(np.asarray(u, float), self.dL)
            return np.column_stack([t2[:, 0], np.zeros(self.N), t2[:, 1]])
        return _geo.tangents(_geo.frames_from_state(np.asarray(u, float)))

    def frames(self, u: Array) -> Array:
        """Quaternions (N, 4) of the material frames."""
        return _geo.frames_from_state(self.full_state(u))

    def segment_positions(self, u: Array) -> Array:
        """Segment centres (N, 3), ``X_1 = 0``."""
        return _geo.positions(self.tangents(u), self.dL)

    def centreline(self, u: Array) -> Array:
        """Points ``Y(s)`` at the base, every joint and the tip ((N+1), 3)."""
        t = self.tangents(u)
        X = _geo.positions(t, self.dL)
        Y = np.empty((self.N + 1, 3))
        Y[0] = X[0] - 0.5 * self.dL * t[0]
        Y[1:] = X + 0.5 * self.dL * t
        return Y

    def draw_state(self, u: Array, kind: str, extra: dict[str, Any], ax: Any = None,
                   n_frames: int = 12) -> Any:
        """Draw state ``u`` of a branch of ``kind`` (plot hook, see :mod:`.views`)."""
        from .views import draw_state

        return draw_state(self, u, kind, extra, ax=ax, n_frames=n_frames)

    def internal_forces(self, u: Array, p: Array) -> dict[str, Array]:
        """Internal force profile at the joints and the clamp reactions.

        Returns ``Lam`` (N-1, 3) (force exerted by segment n+1 on segment n),
        ``s`` (arclength of each joint, ``n dL``), ``tension = Lam . t_mid``
        (negative = compression) with ``t_mid`` the normalised mean of the
        neighbouring tangents, ``shear = |Lam - (Lam . t_mid) t_mid|``, and
        ``Fc``, ``Tc`` (3,).
        """
        _, lam, _ = self.evaluate(u, p)
        N = self.N
        if self.planar:
            Lam = np.zeros((N - 1, 3))
            Lam[:, 0] = lam[0 : 2 * (N - 1) : 2]
            Lam[:, 2] = lam[1 : 2 * (N - 1) : 2]
            c = 2 * (N - 1)
            Fc = np.array([lam[c], 0.0, lam[c + 1]])
            Tc = np.array([0.0, lam[c + 2], 0.0])
        else:
            Lam = lam[: 3 * (N - 1)].reshape(N - 1, 3).copy()
            Fc = lam[3 * (N - 1) : 3 * (N - 1) + 3].copy()
            Tc = lam[3 * (N - 1) + 3 :].copy()
        t = self.tangents(u)
        tm = t[:-1] + t[1:]
        tm /= np.linalg.norm(tm, axis=1)[:, None]
        ten = np.einsum("ij,ij->i", Lam, tm)
        shear = np.linalg.norm(Lam - ten[:, None] * tm, axis=1)
        s = self.dL * np.arange(1, N)
        return {"Lam": Lam, "s": s, "tension": ten, "shear": shear, "Fc": Fc, "Tc": Tc}

    def bending_energy(self, u: Array) -> float:
        """Bending energy of state ``u``: :func:`.physics.bending_energy`
        (``K_B sum_n |t_{n+1} - t_n|^2 / (2 dL)``, the one discrete form)."""
        return bending_energy(self.tangents(u), self.dL, self.physics.KB)

    def observables(self, u: Array, p: Array) -> dict[str, Any]:
        """:func:`.physics.frame_observables` of ``u`` and the state norm.

        Bending energy, tip position (free end ``X_N + dL/2 t_N``), its
        azimuth ``tip_angle`` and distance ``tip_r`` from the e3 axis.
        """
        u = np.asarray(u, dtype=float)
        if not np.isfinite(u).all():
            raise NonFiniteError(f"{self.name}.observables: non-finite state")
        obs: dict[str, Any] = frame_observables(self.tangents(u), self.dL, self.physics.KB)
        obs["norm"] = float(np.linalg.norm(u))
        return obs

    # -- symmetries -------------------------------------------------------
    def _build_symmetries(self) -> Symmetries:
        n1 = self.N - 1
        if self.planar:
            # x -> -x mirror: phi -> -phi
            return Symmetries(reflections={"mirror_x": -np.eye(n1)})
        # U is an axial vector: a mirror P acts as det(P) P = -P on each block
        my = np.kron(np.eye(n1), np.diag([-1.0, 1.0, -1.0]))  # y -> -y
        mx = np.kron(np.eye(n1), np.diag([1.0, -1.0, -1.0]))  # x -> -x
        scene = self.scene

        def embed(phi: Array) -> Array:
            U = np.zeros(3 * n1)
            U[1::3] = phi
            return U

        def project(U: Array) -> Array:
            return np.asarray(U)[1::3].copy()

        def reduced() -> FilamentModel:
            return FilamentModel(scene.replace(dimension="planar"), integrator=self.integrator,
                                 steps_per_period=self.flow_steps_min)

        return Symmetries(
            continuous=[ContinuousSymmetry("rotation_e3", _rz_generator(n1), 2 * np.pi)],
            reflections={"mirror_y": my, "mirror_x": mx},
            invariant_subspaces={
                "planar_xz": InvariantSubspace("planar_xz", embed, project, reduced)
            },
        )
