"""The plug-in contract, re-exported where model authors look for it.

The definitions live in :mod:`contfil.protocol` so that the engine, which
must not import anything under ``contfil.models``, can use them too.
"""

from contfil.protocol import (
    Array,
    ContinuousSymmetry,
    FunctionModel,
    InvariantSubspace,
    Model,
    Symmetries,
    param_index,
)

__all__ = [
    "Array",
    "ContinuousSymmetry",
    "FunctionModel",
    "InvariantSubspace",
    "Model",
    "Symmetries",
    "param_index",
]
