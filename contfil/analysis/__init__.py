"""contfil.analysis: generic long-time analysis tools (no model, graph or store).

One concept per module: :mod:`~contfil.analysis.spod` (spectral POD),
:mod:`~contfil.analysis.lyapunov` (largest Lyapunov exponent),
:mod:`~contfil.analysis.classify` (streaming attractor classification),
:mod:`~contfil.analysis.bisection` (edge tracking),
:mod:`~contfil.analysis.angular` (angular speed, reversals, handedness),
:mod:`~contfil.analysis.decay` (far-field power-law fit). See docs/analysis.md.
"""

from contfil.analysis.angular import (
    angular_speed,
    count_reversals,
    discrete_torsion,
    handedness,
    local_handedness,
)
from contfil.analysis.bisection import EdgeResult, edge_track
from contfil.analysis.classify import AttractorClass, classify_attractor, classify_samples
from contfil.analysis.decay import DecayFit, far_field_decay
from contfil.analysis.lyapunov import LyapunovResult, largest_lyapunov
from contfil.analysis.spod import SPODResult, cross_spectral_density, spod

__all__ = [
    "AttractorClass",
    "DecayFit",
    "EdgeResult",
    "LyapunovResult",
    "SPODResult",
    "angular_speed",
    "classify_attractor",
    "classify_samples",
    "count_reversals",
    "cross_spectral_density",
    "discrete_torsion",
    "edge_track",
    "far_field_decay",
    "handedness",
    "largest_lyapunov",
    "local_handedness",
    "spod",
]
