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


# --- tip SF beyond the first window (issue 12): the planar folds, beating
# with Radau past b1 = 2272, QP3 to its end. Read-only over the stored runs.

TIP_SF_MORE = ["tip_sf_planar", "tip_sf_high_planar", "tip_sf_high2", "tip_sf_high_qp3",
               "tip_sf_high3", "tip_sf_high_qp3_radau"]


@pytest.mark.parametrize("name", TIP_SF_MORE)
def test_tip_sf_follow_up_specs_load_and_report_the_bending_energy(name: str) -> None:
    from contfil.app.study import known_observables

    spec = load_spec(ROOT / "branches" / f"{name}.toml")
    info = build_model(spec)
    seed = root_seed(spec, info)
    lo, hi = spec.continuation["range"]
    assert lo <= seed.p0 <= hi
    # the ordinate of the diagram, read at the model state (a planar started
    # cycle's unknowns are the state and the period)
    assert "bending_energy" in known_observables(info, seed)
    if "start" in seed.info:
        # beating (a planar cycle), or QP3 (a drifting orbit) for the QP3 spec
        want = "relative_periodic_orbit" if name.endswith("qp3") else "periodic_orbit"
        assert seed.kind == want


def _folds(run: str) -> tuple[object, list[object]]:
    g = load_run_graph(ROOT / "branches" / "data" / run)
    br = g.branch("B0")
    folds = [g.special_point(s) for s in g.special_points_on("B0")]
    return br, [sp for sp in folds if sp.kind == "cycle_fold"]


def test_planar_tip_sf_has_beating_inter_beating_and_buckled_beating_joined_by_two_folds() -> None:
    br, folds = _folds("tip_sf_high_planar")
    assert br.kind == "periodic_orbit"
    lpc1, lpc2 = folds[0], folds[1]
    assert lpc1.point.p > lpc2.point.p
    p = np.array([pt.p for pt in br.points])
    nu = np.array([pt.n_unstable for pt in br.points])
    i1, i2 = lpc1.index, lpc2.index
    # beating: stable up to the first fold, where it is annihilated
    assert np.all(nu[: i1 + 1] == 0) and np.all(np.diff(p[: i1 + 1]) > 0)
    # the turning point, to the fold's localisation error (~2e-7 in b1: the
    # zero of the tangent's p-component is bracketed in arclength)
    assert p[i1] <= lpc1.point.p + 1e-6 and p[i1 + 1] <= lpc1.point.p + 1e-6
    # inter-beating: the way back down to the second fold, unstable
    assert np.all(nu[i1 + 1: i2 + 1] >= 1) and p[i2 + 1] >= lpc2.point.p - 1e-6
    # buckled-beating: from the second fold up to the window's end, stable there
    assert p[-1] == br.points[-1].p == 2600.0 and nu[-1] == 0
    # three coexisting orbits between the folds
    mid = 0.5 * (lpc1.point.p + lpc2.point.p)
    assert int(np.sum(np.diff(np.sign(p - mid)) != 0)) == 3
    # at a fold of cycles a second multiplier sits at +1 beside the trivial one
    for sp in (lpc1, lpc2):
        mu = np.asarray(sp.point.eigenvalues)
        assert np.sum(np.abs(mu - 1.0) < 1e-3) >= 2


def test_3d_tip_sf_beating_has_the_planar_folds_and_the_pitchforks_of_both_states() -> None:
    br3, folds3 = _folds("tip_sf_high2")
    _, folds2 = _folds("tip_sf_high_planar")
    # the cycle lies in the planar subspace: the planar model's folds, to the
    # localisation tolerance (the same integrator and resolution)
    for a, b in zip(folds3[:2], folds2[:2], strict=True):
        assert abs(a.point.p - b.point.p) < 1e-6
    g = load_run_graph(ROOT / "branches" / "data" / "tip_sf_high2")
    bpc = [g.special_point(s) for s in g.special_points_on("B0")
           if g.special_point(s).kind == "cycle_branch_point"]
    # out-of-plane pitchforks: two of beating below the first fold, its merge,
    # one on inter-beating, and on buckled-beating beyond the second fold
    lpc1, lpc2 = folds3[0], folds3[1]
    on_beating = [sp for sp in bpc if sp.index < lpc1.index]
    on_inter = [sp for sp in bpc if lpc1.index <= sp.index < lpc2.index]
    on_buckled = [sp for sp in bpc if sp.index >= lpc2.index]
    assert len(on_beating) == 3 and len(on_inter) >= 1 and len(on_buckled) >= 1
    assert all(sp.data.get("event") == "subspace_breaking" for sp in bpc)
    # no branch point of the cycle system itself at the folds (the spurious
    # BPC of the last session's run, at LPC2)
    assert not any(abs(sp.point.p - lpc2.point.p) < 1e-3 for sp in bpc)
    assert br3.points[-1].n_unstable == 0


def test_3d_tip_sf_buckled_beating_loses_stability_by_tori_and_leads_to_quasiperiodic_states(
) -> None:
    """Stored ``tip_sf_high3`` (buckled-beating from b1 = 3000): stable at its
    start, two tori (in the plane, then out of it) reported by the torus event
    itself with their complex pairs on the unit circle, and the simulated
    states beyond joined to the first torus."""
    g = load_run_graph(ROOT / "branches" / "data" / "tip_sf_high3")
    br = g.branch("B0")
    assert br.points[0].n_unstable == 0
    sps = [g.special_point(s) for s in g.special_points_on("B0")]
    tori = [sp for sp in sps if sp.kind == "torus"]
    assert [round(sp.point.p, 1) for sp in tori] == [3727.5, 3778.9]
    assert not any(sp.kind == "stability_change" for sp in sps)
    for sp in tori:
        assert abs(abs(complex(sp.data["multiplier"])) - 1.0) < 1e-6
        assert sp.data["multiplier"] != 1.0 and abs(sp.data["p_error"]) < 0.05
    ns1 = g.special_id(g.label(g.special_points_on("B0")[sps.index(tori[0])]))
    states = g.states_from(ns1)
    # session 10's 4000 and 5000, then session 14's planar tori above 5000
    # (tests/test_tip_sf_chaos_search.py checks those)
    assert {g.state(a)["kind"] for a in states} == {"quasiperiodic"}
    assert sorted(g.state(a)["p"] for a in states)[:2] == [4000.0, 5000.0]


def test_3d_tip_sf_qp3_in_radau_has_its_own_pitchfork_where_bpc6s_family_ends() -> None:
    """Stored ``tip_sf_high_qp3_radau``: QP3 born at beating's second
    out-of-plane pitchfork (2145.77) drifts, and has a pitchfork of its own
    near b1 = 2179.91, where its unstable multiplier returns inside: the point
    where the drifting branch from BPC6's family ends (session 10, located
    there at 2179.9083 +- 4e-4 from the other side; docs/high-actuation.md)."""
    g = load_run_graph(ROOT / "branches" / "data" / "tip_sf_high_qp3_radau")
    bpc1 = g.special_point("BPC1")
    assert bpc1.data["event"] == "subspace_breaking"
    assert abs(bpc1.point.p - 2145.7657) < 1e-3 and abs(bpc1.data["p_error"]) < 1e-3
    qp3 = g.branch("B1")
    assert qp3.kind == "relative_periodic_orbit"
    assert all(abs(pt.extra["drift"]) > 0.04 for pt in qp3.points)
    bpc2 = g.special_point("BPC2")
    assert g.special_id("BPC2") in g.special_points_on("B1")
    assert abs(bpc2.point.p - 2179.9083) < 1e-3 and abs(bpc2.data["p_error"]) < 1e-3
    assert abs(complex(bpc2.data["multiplier"]) - 1.0) < 1e-5
    below = [pt.n_unstable for pt in qp3.points if pt.p < bpc2.point.p]
    above = [pt.n_unstable for pt in qp3.points if pt.p > bpc2.point.p]
    assert set(below) == {1} and set(above) == {0}


@pytest.mark.parametrize("f", [420.0, 440.0])
def test_3d_tip_ff_beyond_the_first_torus_is_chaotic_along_the_whole_classified_window(
    f: float,
) -> None:
    """Stored ``tip_ff_high_radau``: the states simulated at f = 420 and 440
    (between beating's tori NS1 407.35 and NS2 508.59), joined to NS1, are
    chaotic by an exponent measured along the classified trajectory
    (decisions 39): more than three errors above zero, every block mean
    positive, over the whole window of 1000 periods after 1000 discarded,
    with a broadband spectrum."""
    g = load_run_graph(ROOT / "branches" / "data" / "tip_ff_high_radau")
    ns1 = g.special_id("NS1")
    assert g.special_point(ns1).kind == "torus"
    (a,) = [s for s in g.states_from(ns1) if g.state(s)["p"] == f]
    st = g.state(a)
    ev = st["evidence"]
    assert st["kind"] == "chaotic" and ev["label"] == "chaotic"
    assert ev["lyapunov_method"] == "lockstep" and ev["lyapunov_skip_maps"] == 0
    # the exponent's maps cover the classified window exactly
    assert ev["lyapunov_maps"] * ev["lyapunov_map_steps"] == ev["n_samples"] * ev["sample_every"]
    assert ev["transient_steps"] >= 300 * ev["lyapunov_map_steps"]
    assert ev["lyapunov"] > 3 * ev["lyapunov_error"] > 0
    assert min(ev["lyapunov_block_means"]) > 0
    assert ev["discrete_fraction"] < 0.98


def test_dis_sf_in_radau_has_both_tori_with_error_estimates() -> None:
    """Stored ``dis_sf_high_radau``: beating's complex pair leaves the unit
    circle at NS1 (towards QP2) and returns at NS2, both located by the torus
    event with a p_error from a refined problem; QP2's state node is joined
    to NS1."""
    g = load_run_graph(ROOT / "branches" / "data" / "dis_sf_high_radau")
    br = g.branch("B0")
    tori = [g.special_point(s) for s in g.special_points_on("B0")]
    assert [sp.kind for sp in tori] == ["torus", "torus"]
    for sp, ref in zip(tori, (655.3117, 3658.718), strict=True):
        assert abs(sp.point.p - ref) < 1e-3 and abs(sp.data["p_error"]) < 1e-3
        assert abs(abs(complex(sp.data["multiplier"])) - 1.0) < 1e-8
    ns1, ns2 = (sp.point.p for sp in tori)
    assert all(pt.n_unstable == 0 for pt in br.points if pt.p < ns1 or pt.p > ns2)
    assert all(pt.n_unstable == 2 for pt in br.points if ns1 < pt.p < ns2)
    (a,) = g.states_from("NS1")
    assert g.state(a)["kind"] == "quasiperiodic"


def test_tip_ff_beating_beyond_f_1000_is_not_annihilated_and_restabilises() -> None:
    """Stored ``tip_ff_high_radau2`` (beating from f = 1000): no fold of
    beating up to where the branch stops (2328.7); its two small-angle complex
    pairs return inside the circle at 2096.80 (the safety net's report, the
    pairs' angle 0.025 rad being below the resolved angle), stable up to the
    out-of-plane pitchfork at 2236.72, which switches to B1."""
    g = load_run_graph(ROOT / "branches" / "data" / "tip_ff_high_radau2")
    br = g.branch("B0")
    sps = [g.special_point(s) for s in g.special_points_on("B0")]
    assert not any(sp.kind == "cycle_fold" for sp in sps)
    sc = next(sp for sp in sps if sp.kind == "stability_change")
    bpc = next(sp for sp in sps if sp.kind == "cycle_branch_point")
    assert (sc.data["count_before"], sc.data["count_after"]) == (4, 0)
    assert abs(sc.point.p - 2096.80) < 0.01 and abs(bpc.point.p - 2236.72) < 0.01
    assert bpc.data["event"] == "subspace_breaking" and abs(bpc.data["p_error"]) < 1e-3
    assert all(pt.n_unstable == 0 for pt in br.points if sc.point.p < pt.p < bpc.point.p)
    assert all(pt.n_unstable == 4 for pt in br.points if pt.p < sc.point.p)
    assert br.points[-1].p > 2328.0


def test_dis_ff_in_radau_every_special_point_of_beating_has_an_error_estimate() -> None:
    """Stored ``dis_ff_high_radau``: beating's pitchfork to bent-beating, its
    annihilation at a fold of cycles, the torus of its unstable partner
    (reported by the torus event since decisions 40, not as a stability
    change) and two more pitchforks, each with a p_error from a refined
    problem; bent-beating's torus; the chaotic state joined to it."""
    g = load_run_graph(ROOT / "branches" / "data" / "dis_ff_high_radau")
    on_b0 = {g.label(s): g.special_point(s) for s in g.special_points_on("B0")}
    assert {k: sp.kind for k, sp in on_b0.items()} == {
        "BPC1": "cycle_branch_point", "LPC1": "cycle_fold", "NS1": "torus",
        "BPC2": "cycle_branch_point", "BPC3": "cycle_branch_point"}
    for sp in on_b0.values():
        assert abs(sp.data["p_error"]) < 0.01
    assert abs(on_b0["BPC1"].point.p - 111.562) < 1e-3
    assert abs(on_b0["LPC1"].point.p - 197.698) < 1e-2
    ns1 = on_b0["NS1"]
    assert abs(abs(complex(ns1.data["multiplier"])) - 1.0) < 1e-8
    ns2 = g.special_point("NS2")
    assert g.special_id("NS2") in g.special_points_on("B1") and ns2.kind == "torus"
    assert abs(ns2.point.p - 175.03) < 0.01
    (a,) = g.states_from("NS2")
    assert g.state(a)["kind"] == "chaotic"


def test_tip_ff_beating_goes_past_the_chart_cut_at_2328_unannihilated_to_3000() -> None:
    """Stored ``tip_ff_high_radau3`` (session 12): beating restarted where
    ``tip_ff_high_radau2`` stopped (f = 2328.72). There the phase origin had
    one segment's rotation vector at |U| = π, the cut of the state's chart
    (decisions 42); the engine moved the origin along the orbit (to
    max |U| ≈ 1.04) and the branch goes on, the same orbit (period and mean
    bending energy continuous), to f = 3000 with no fold of cycles and no
    other special point: one unstable (out-of-plane) multiplier throughout,
    the period falling monotonically."""
    data = ROOT / "branches" / "data"
    old = load_run_graph(data / "tip_ff_high_radau2").branch("B0").points[-1]
    g = load_run_graph(data / "tip_ff_high_radau3")
    assert g.special_points_on("B0") == []
    pts = g.branch("B0").points
    assert pts[0].p == old.p and pts[-1].p == 3000.0
    np.testing.assert_array_equal(pts[0].u, old.u)

    def max_rotation(pt) -> float:  # noqa: ANN001
        return float(np.linalg.norm(pt.u.reshape(-1, 3), axis=1).max())

    assert abs(max_rotation(pts[0]) - np.pi) < 1e-4
    assert all(max_rotation(pt) < 1.2 for pt in pts[1:])
    T = np.array([pt.extra["period"] for pt in pts])
    E = np.array([pt.observables["mean_bending_energy"] for pt in pts])
    assert abs(T[1] - T[0]) / T[0] < 1e-3 and abs(E[1] - E[0]) / E[0] < 1e-3
    assert np.all(np.diff(T) < 0.0) and np.all(np.diff(E) > 0.0)
    assert all(pt.n_unstable == 1 for pt in pts)
    lead = [float(np.max(np.abs(pt.eigenvalues[~pt.trivial]))) for pt in pts]
    assert lead[0] == pytest.approx(1.1585, abs=1e-3) and lead[-1] > 30.0
