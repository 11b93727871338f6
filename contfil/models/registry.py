"""The model registry: the model a spec's ``[scene]`` or ``[model]`` table names.

A ``[scene]`` table builds the filament plug-in; a ``[model]`` table names a
factory of :mod:`contfil.models.catalog` with parameter overrides.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any

import numpy as np

from contfil.errors import SpecError

_NOT_MODELS = {"CatalogEntry", "bratu_fold_exact", "bratu_solution"}


def catalog_names() -> list[str]:
    """Names of the catalog models (factories in ``contfil.models.catalog``)."""
    cat = importlib.import_module("contfil.models.catalog")
    names = getattr(cat, "__all__", [n for n in dir(cat) if not n.startswith("_")])
    return sorted(n for n in names if n not in _NOT_MODELS and callable(getattr(cat, n, None)))


@dataclass
class ModelInfo:
    """A model with the starting data its source suggests."""

    model: Any
    param: str | None = None
    u0: np.ndarray | None = None
    p0: float | None = None


def catalog_model(name: str, params: dict[str, float] | None = None) -> ModelInfo:
    """Catalog model ``name`` (a factory returning a ``CatalogEntry``) with
    parameter overrides ``params``."""
    cat = importlib.import_module("contfil.models.catalog")
    if name not in catalog_names():
        raise SpecError(f"model.name: unknown catalog model {name!r}; known: {catalog_names()}")
    entry = getattr(cat, name)()
    model = getattr(entry, "model", entry)
    info = ModelInfo(model=model, param=getattr(entry, "param", None),
                     u0=getattr(entry, "u0", None), p0=getattr(entry, "p0", None))
    if params:
        info.model = _with_params(model, params)
        if info.param in params:
            info.p0 = float(params[info.param])
    return info


class _ParamOverride:
    """A model whose ``default_params`` are overridden (everything else delegated)."""

    def __init__(self, model: Any, defaults: np.ndarray) -> None:
        self._m = model
        self._defaults = defaults

    def default_params(self) -> np.ndarray:
        return self._defaults.copy()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._m, name)


def _with_params(model: Any, params: dict[str, float]) -> Any:
    p = np.array(model.default_params(), dtype=float)
    for k, v in params.items():
        if k not in model.param_names:
            raise SpecError(
                f"model.params.{k}: model {model.name!r} has no such parameter; "
                f"known: {list(model.param_names)}")
        p[list(model.param_names).index(k)] = float(v)
    return _ParamOverride(model, p)


def build_model(scene: dict[str, Any] | None = None,
                model: dict[str, Any] | None = None,
                integrator: dict[str, Any] | None = None) -> ModelInfo:
    """The model a spec describes: ``FilamentModel`` for a ``[scene]`` table
    (with the time stepper of an ``[integrator]`` table: ``method``,
    ``steps_per_period``), else the catalog model named by a ``[model]``
    table (``name``, ``params``)."""
    if scene is not None:
        from contfil.models.filament.model import FilamentModel

        integ = integrator or {}
        spp = integ.get("steps_per_period")
        m = FilamentModel({"scene": scene}, integrator=str(integ.get("method") or "bdf2"),
                          steps_per_period=int(spp) if spp else None)
        return ModelInfo(model=m, param=m.scene.param_name)
    if model is None:
        raise SpecError("spec: needs a [scene] table (filament) or a [model] table (catalog)")
    return catalog_model(model["name"], model.get("params") or {})
