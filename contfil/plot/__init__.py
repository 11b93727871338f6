"""contfil.plot: bifurcation diagrams, eigenvalue curves, shape plots of a run."""

from contfil.plot.diagrams import (
    bifurcation_diagram,
    eigenvalue_plot,
    save_run_plots,
    track_eigenvalues,
)
from contfil.plot.shapes import branch_snapshots, save_shape_plots

__all__ = ["bifurcation_diagram", "branch_snapshots", "eigenvalue_plot", "save_run_plots",
           "save_shape_plots", "track_eigenvalues"]
