"""The high-actuation specs (``branches/*_high.toml``, issue 12) start where
the stored moderate-actuation runs end: stable planar beating at the top of
their window, solved in the planar subspace, with the stored solution as the
first point (its residual is converged, nothing is recomputed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from contfil.app.spec import load_spec
from contfil.app.study import build_model, root_seed
from contfil.store.run_store import load_run_graph

ROOT = Path(__file__).resolve().parents[1]
HIGH = sorted((ROOT / "branches").glob("*_high.toml"))


@pytest.mark.parametrize("path", HIGH, ids=[p.stem for p in HIGH])
def test_high_spec_starts_from_stable_beating_at_the_top_of_the_stored_run(path: Path) -> None:
    spec = load_spec(path)
    info = build_model(spec)
    seed = root_seed(spec, info)
    start = seed.info["start"]
    stored = load_run_graph(start["run"])
    br = stored.branch(start["branch"])
    pt = br.points[start["index"]]
    # beating: the stored cycle branch, at the top of the stored window, stable in 3-D
    assert br.kind == "periodic_orbit" == seed.kind
    assert pt.p == stored.meta["range"][1] == spec.continuation["range"][0]
    assert pt.n_unstable == 0
    # solved where the double-Hopf switcher solved it: the planar subspace
    assert start["subspace"] == "planar_xz" and seed.problem.subspace is not None
    sub = seed.problem.subspace
    np.testing.assert_allclose(sub.embed(seed.x0[: seed.problem.dim]), pt.u, atol=1e-14)
    assert seed.x0[-1] == pt.extra["period"]
    assert seed.direction == 1 and spec.explorer["depth"] >= 1
