"""contfil.engine: generic continuation (knows nothing about filaments).

Public API::

    from contfil.engine import (
        EquilibriumProblem, Continuation, ContinuationSettings, continue_branch,
        Event, EventContext, FoldEvent, BranchPointEvent, HopfEvent,
        switch_at_branch_point, branch_point_tangents, hopf_data,
    )
"""

from contfil.engine.branch import Branch, Point, SpecialPoint
from contfil.engine.continuation.driver import Continuation, ContinuationSettings, continue_branch
from contfil.engine.events.standard import (
    BranchPointEvent,
    Event,
    EventContext,
    FoldEvent,
    HopfEvent,
    NodeFocusEvent,
    default_events,
)
from contfil.engine.linalg.eigen import dense_stability, shift_invert_stability
from contfil.engine.linalg.newton import NewtonInfo, newton_dense, newton_krylov
from contfil.engine.problems.base import Problem, Stability
from contfil.engine.problems.equilibrium import EquilibriumProblem
from contfil.engine.switching.equilibria import (
    branch_point_tangents,
    hopf_data,
    hopf_normal_form,
    o2_hopf_modes,
    switch_at_branch_point,
)

__all__ = [
    "Branch",
    "BranchPointEvent",
    "Continuation",
    "ContinuationSettings",
    "EquilibriumProblem",
    "Event",
    "EventContext",
    "FoldEvent",
    "HopfEvent",
    "NewtonInfo",
    "NodeFocusEvent",
    "Point",
    "Problem",
    "SpecialPoint",
    "Stability",
    "continue_branch",
    "default_events",
    "dense_stability",
    "newton_dense",
    "newton_krylov",
    "shift_invert_stability",
    "branch_point_tangents",
    "hopf_data",
    "hopf_normal_form",
    "o2_hopf_modes",
    "switch_at_branch_point",
]
