"""contfil.plot: bifurcation diagrams, eigenvalue curves, filament views."""

from contfil.plot.diagrams import (
    bifurcation_diagram,
    branch_snapshots,
    eigenvalue_plot,
    filament_snapshots,
    save_run_plots,
)

__all__ = ["bifurcation_diagram", "branch_snapshots", "eigenvalue_plot", "filament_snapshots",
           "save_run_plots"]
