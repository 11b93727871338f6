"""contfil.graph: the graph of connected states (data only)."""

from contfil.graph.branch_graph import BranchGraph
from contfil.graph.identity import same_branch, same_special_point

__all__ = ["BranchGraph", "same_branch", "same_special_point"]
