"""Property-based fuzzing (hypothesis): the spec loader and damaged run
directories never end in a traceback: a valid result or one clear error."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from faults import HOPF_SPEC
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from contfil.app.cli import main
from contfil.app.spec import SCHEMA, TOP_KEYS, load_spec, parse_spec
from contfil.app.study import build_model, engine_settings, require_continuation, root_seed
from contfil.errors import ContfilError
from contfil.graph.branch_graph import BranchGraph

VALID = {
    "model": {"name": "hopf_2d"},
    "continuation": {"range": [-1.0, 0.6], "ds": 0.1, "ds_max": 0.2, "max_points": 12},
    "explorer": {"depth": 1},
    "output": {"plots": False, "graphml": False},
}

# TOML values: scalars, arrays, tables (what tomllib can hand to the loader).
scalars = st.one_of(st.booleans(), st.integers(-10**6, 10**6),
                    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=12))
values = st.recursive(scalars, lambda inner: st.one_of(
    st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=8), inner, max_size=4)),
    max_leaves=8)
key_names = st.sampled_from(sorted({k for t in SCHEMA.values() for k in t} | {"N", "x", ""}))
table_names = st.sampled_from([*TOP_KEYS, "nonsense"])


def _check_spec_doc(doc: object) -> None:
    """Load and set up a study from ``doc``: valid, or one ContfilError."""
    try:
        spec = parse_spec(doc)  # type: ignore[arg-type]
        if spec.model is not None:  # catalog models are cheap to build
            require_continuation(spec)
            info = build_model(spec)
            root_seed(spec, info)
            engine_settings(spec)
    except ContfilError as exc:
        msg = str(exc)
        assert msg and "Traceback" not in msg


@settings(max_examples=300, deadline=None)
@given(st.dictionaries(table_names, values, max_size=4))
def test_spec_loader_random_tables(doc: dict) -> None:
    _check_spec_doc(doc)


@settings(max_examples=300, deadline=None)
@given(table=st.sampled_from(["model", "continuation", "explorer", "output", "simulate"]),
       key=key_names, value=values, drop=st.booleans())
def test_spec_loader_mutated_valid_spec(table: str, key: str, value: object,
                                        drop: bool) -> None:
    doc = {t: dict(v) for t, v in VALID.items()}
    doc.setdefault(table, {})
    if drop and key in doc[table]:
        del doc[table][key]
    else:
        doc[table][key] = value
    _check_spec_doc(doc)


@settings(max_examples=200, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.one_of(st.binary(max_size=300),
                      st.text(max_size=300).map(lambda t: t.encode("utf-8", "replace"))))
def test_spec_file_random_bytes(tmp_path: Path, data: bytes) -> None:
    path = tmp_path / "fuzz.toml"
    path.write_bytes(data)
    try:
        load_spec(path)
    except ContfilError as exc:
        assert str(exc).startswith(f"{path}: ") or ": expected" in str(exc) or str(exc)


# ------------------------------------------------------------ damaged runs
SPEC = HOPF_SPEC


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("fuzzrun")
    (d / "spec.toml").write_text(SPEC)
    assert main(["run", str(d / "spec.toml"), "--out", str(d / "run"), "--quiet"]) == 0
    return d / "run"


def _files(run: Path) -> list[Path]:
    return sorted(p for p in run.rglob("*") if p.is_file() and p.name != ".lock")


damage_op = st.tuples(st.sampled_from(["truncate", "flip", "delete", "garbage", "empty"]),
                      st.integers(0, 10**6), st.binary(min_size=1, max_size=64))


def _damage(run: Path, ops: list[tuple[str, int, bytes]]) -> list[str]:
    done = []
    for op, where, junk in ops:
        files = _files(run)
        if not files:
            break
        f = files[where % len(files)]
        data = f.read_bytes()
        if op == "truncate":
            f.write_bytes(data[: where % (len(data) + 1)])
        elif op == "flip" and data:
            k = where % len(data)
            f.write_bytes(data[:k] + bytes([data[k] ^ (1 + junk[0] % 255)]) + data[k + 1:])
        elif op == "delete":
            f.unlink()
        elif op == "garbage":
            f.write_bytes(junk)
        elif op == "empty":
            f.write_bytes(b"")
        done.append(f"{op} {f.relative_to(run)}")
    return done


def _run_cli(args: list[str], capsys) -> tuple[int, str]:
    code = main(args)
    err = capsys.readouterr().err
    if code != 0:
        # One line naming the problem, never a traceback or an unexpected exception.
        lines = [ln for ln in err.splitlines() if not ln.startswith("contfil: warning:")]
        assert len(lines) == 1 and lines[0].startswith("contfil: error: "), err
        assert "unexpected" not in err and "Traceback" not in err, err
    return code, err


@settings(max_examples=40, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(ops=st.lists(damage_op, min_size=1, max_size=3))
def test_damaged_run_show_export(finished_run: Path, tmp_path_factory, capsys,
                                 ops: list) -> None:
    run = tmp_path_factory.mktemp("dmg") / "run"
    shutil.copytree(finished_run, run)
    _damage(run, ops)
    _run_cli(["show", str(run)], capsys)
    _run_cli(["export", str(run), "--format", "graphml", "-o", str(run.parent / "g.graphml")],
             capsys)
    _run_cli(["export", str(run), "--states", "-o", str(run.parent / "s.json")], capsys)


@settings(max_examples=6, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(ops=st.lists(damage_op, min_size=1, max_size=2))
def test_damaged_run_plot(finished_run: Path, tmp_path_factory, capsys, ops: list) -> None:
    run = tmp_path_factory.mktemp("dmg") / "run"
    shutil.copytree(finished_run, run)
    _damage(run, ops)
    _run_cli(["plot", str(run), "--out", str(run.parent / "plots")], capsys)


@settings(max_examples=10, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(ops=st.lists(damage_op, min_size=1, max_size=2))
def test_damaged_run_resume(finished_run: Path, tmp_path_factory, capsys, ops: list) -> None:
    run = tmp_path_factory.mktemp("dmg") / "run"
    shutil.copytree(finished_run, run)
    spec = run.parent / "spec.toml"
    spec.write_text(SPEC)
    _damage(run, ops)
    code, _ = _run_cli(["run", str(spec), "--out", str(run), "--quiet", "--resume"], capsys)
    if code == 0:
        # A resume that succeeds recomputes what was lost: the uninterrupted
        # run's graph (equilibria exactly; cycles: see the crash harness).
        assert _run_cli(["show", str(run)], capsys)[0] == 0
        a = BranchGraph.load_json(finished_run / "graph.json")
        b = BranchGraph.load_json(run / "graph.json")
        assert [x.kind for x in a.branches.values()] == [x.kind for x in b.branches.values()]
        pa, pb = a.branch("B0").points, b.branch("B0").points
        assert len(pa) == len(pb)
        for x, y in zip(pa, pb, strict=True):
            assert abs(x.p - y.p) <= 1e-12 and np.max(np.abs(x.u - y.u)) <= 1e-12


@settings(max_examples=150, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.one_of(st.binary(max_size=200),
                      st.sampled_from([b"{}", b"[]", b"null", b'{"nodes": 1, "edges": []}',
                                       b"<graphml/>", b"<graphml><graph><node/></graph>",
                                       b'{"directed": true, "nodes": [{"id": "B0"}]}']),
                      st.text(max_size=200).map(lambda t: t.encode())),
       suffix=st.sampled_from([".json", ".graphml"]))
def test_graph_file_random_bytes(tmp_path: Path, data: bytes, suffix: str) -> None:
    from contfil.store.run_store import load_run_graph

    path = tmp_path / f"graph{suffix}"
    path.write_bytes(data)
    try:
        load_run_graph(path)
    except ContfilError as exc:
        assert str(path) in str(exc)
