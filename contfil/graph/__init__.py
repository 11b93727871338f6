"""contfil.graph: the graph of connected states and the automatic explorer."""

from contfil.graph.branch_graph import BranchGraph
from contfil.graph.explorer import Explorer, ExplorerSettings
from contfil.graph.identity import same_branch, same_special_point
from contfil.graph.seeds import Seed, SwitcherRegistry

__all__ = ["BranchGraph", "Explorer", "ExplorerSettings", "Seed", "SwitcherRegistry",
           "same_branch", "same_special_point"]
