"""Textbook systems with exactly known bifurcation points (engine tests).

Each factory returns a :class:`CatalogEntry` (model, parameter name, start,
exact answers). Cycle systems live in ``cycles_*.py`` modules.
"""

from contfil.models.catalog.bratu import bratu, bratu_fold_exact, bratu_solution
from contfil.models.catalog.brusselator import brusselator, brusselator_1d
from contfil.models.catalog.chafee_infante import chafee_infante
from contfil.models.catalog.normal_forms import (
    CatalogEntry,
    bautin_2d,
    hopf_2d,
    hopf_with_real_pair,
    o2_hopf,
    pitchfork,
    saddle_node,
    transcritical,
    z2_pitchfork,
)

__all__ = [
    "CatalogEntry",
    "bautin_2d",
    "bratu",
    "bratu_fold_exact",
    "bratu_solution",
    "brusselator",
    "brusselator_1d",
    "chafee_infante",
    "hopf_2d",
    "hopf_with_real_pair",
    "o2_hopf",
    "pitchfork",
    "saddle_node",
    "transcritical",
    "z2_pitchfork",
]
