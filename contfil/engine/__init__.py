"""contfil.engine: generic continuation (knows nothing about filaments).

Public API (equilibria, rotating waves, periodic and relative periodic
orbits)::

    from contfil.engine import (
        EquilibriumProblem, RotatingWaveProblem, PeriodicOrbitProblem,
        RelativePeriodicOrbitProblem, MultipleShootingProblem,
        RelativeMultipleShootingProblem, CollocationProblem, CycleFoldCurveProblem,
        Continuation, ContinuationSettings, ContinuationState, continue_branch,
        Event, EventContext, FoldEvent, BranchPointEvent, HopfEvent, cycle_events,
        switch_at_branch_point, branch_point_tangents, hopf_data,
        cycles_from_hopf, rotating_wave_from_double_hopf, floquet_multipliers,
        newton_hookstep, hookstep_corrector,
    )
"""

from contfil.engine.branch import Branch, Point, SpecialPoint
from contfil.engine.continuation.driver import Continuation, continue_branch
from contfil.engine.continuation.settings import ContinuationSettings
from contfil.engine.continuation.state import ContinuationState
from contfil.engine.events.cycles import (
    CycleBranchPointEvent,
    CycleFoldEvent,
    PeriodDoublingEvent,
    SubspaceBreakingEvent,
    TorusEvent,
    cycle_events,
)
from contfil.engine.events.standard import (
    BranchPointEvent,
    Event,
    EventContext,
    FoldEvent,
    HopfEvent,
    NodeFocusEvent,
    default_events,
)
from contfil.engine.flows.ops import FlowOps, flow_ops
from contfil.engine.flows.radau import RadauFlow
from contfil.engine.linalg.eigen import dense_stability, normalise_phase, shift_invert_stability
from contfil.engine.linalg.floquet import arnoldi_eigs, flag_trivial, floquet_multipliers
from contfil.engine.linalg.hookstep import hookstep_corrector, newton_hookstep
from contfil.engine.linalg.newton import NewtonInfo, newton_dense, newton_krylov
from contfil.engine.problems.base import Problem, Stability
from contfil.engine.problems.collocation import CollocationProblem
from contfil.engine.problems.cycle_fold_curve import CycleFoldCurveProblem
from contfil.engine.problems.equilibrium import EquilibriumProblem
from contfil.engine.problems.multiple_shooting import (
    MultipleShootingProblem,
    RelativeMultipleShootingProblem,
)
from contfil.engine.problems.rotating_wave import RotatingWaveProblem, rotating_wave_by_shooting
from contfil.engine.problems.shooting import PeriodicOrbitProblem, RelativePeriodicOrbitProblem
from contfil.engine.switching.cycles import (
    BranchStart,
    cycles_from_branch_point,
    cycles_from_hopf,
    cycles_from_period_doubling,
    cycles_leaving_subspace,
    rotating_wave_from_double_hopf,
    standing_wave_from_double_hopf,
)
from contfil.engine.switching.equilibria import (
    branch_point_tangents,
    hopf_data,
    o2_hopf_modes,
    switch_at_branch_point,
)
from contfil.engine.switching.normal_form import hopf_normal_form

__all__ = [
    "CollocationProblem",
    "MultipleShootingProblem",
    "RelativeMultipleShootingProblem",
    "Branch",
    "BranchPointEvent",
    "BranchStart",
    "Continuation",
    "ContinuationSettings",
    "ContinuationState",
    "CycleBranchPointEvent",
    "CycleFoldCurveProblem",
    "CycleFoldEvent",
    "EquilibriumProblem",
    "Event",
    "EventContext",
    "FlowOps",
    "FoldEvent",
    "HopfEvent",
    "NewtonInfo",
    "NodeFocusEvent",
    "PeriodDoublingEvent",
    "PeriodicOrbitProblem",
    "Point",
    "Problem",
    "RadauFlow",
    "RelativePeriodicOrbitProblem",
    "RotatingWaveProblem",
    "SpecialPoint",
    "Stability",
    "SubspaceBreakingEvent",
    "TorusEvent",
    "arnoldi_eigs",
    "branch_point_tangents",
    "continue_branch",
    "cycle_events",
    "cycles_from_branch_point",
    "cycles_from_hopf",
    "cycles_from_period_doubling",
    "cycles_leaving_subspace",
    "default_events",
    "dense_stability",
    "flag_trivial",
    "floquet_multipliers",
    "flow_ops",
    "hookstep_corrector",
    "hopf_data",
    "hopf_normal_form",
    "newton_dense",
    "newton_hookstep",
    "newton_krylov",
    "normalise_phase",
    "o2_hopf_modes",
    "rotating_wave_by_shooting",
    "rotating_wave_from_double_hopf",
    "shift_invert_stability",
    "standing_wave_from_double_hopf",
    "switch_at_branch_point",
]
