"""The notebooks in docs/notebooks run top to bottom (nbclient, kernel python3).

Each runs in a temporary working copy (the notebooks, the specs and the
stored run they read), from its ``docs/notebooks`` folder, with this
checkout's ``contfil`` on the kernel's path and ``TMPDIR`` inside the copy:
nothing is written into the checkout.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")

REPO = Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((REPO / "docs" / "notebooks").glob("*.ipynb"))


def _working_copy(dest: Path) -> Path:
    """The files the notebooks read, copied under ``dest`` in the repo layout."""
    (dest / "docs").mkdir(parents=True)
    shutil.copytree(REPO / "docs" / "notebooks", dest / "docs" / "notebooks")
    (dest / "branches").mkdir()
    for spec in (REPO / "branches").glob("*.toml"):
        shutil.copy(spec, dest / "branches")
    stored = REPO / "branches" / "data" / "tip_sf"
    if (stored / "graph.json").is_file():
        (dest / "branches" / "data" / "tip_sf").mkdir(parents=True)
        for f in ("graph.json", "spec.toml", "run.json"):
            shutil.copy(stored / f, dest / "branches" / "data" / "tip_sf")
    (dest / "tmp").mkdir()
    return dest


def _run(nb_path: Path, cwd: Path, tmp: Path, cells: int | None = None) -> object:
    nb = nbformat.read(nb_path, as_version=4)
    if cells is not None:
        nb.cells = nb.cells[:cells]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(REPO)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]),
        TMPDIR=str(tmp), MPLBACKEND="Agg")
    env.pop("CONTFIL_ROOT", None)
    client = nbclient.NotebookClient(nb, timeout=300, kernel_name="python3",
                                     resources={"metadata": {"path": str(cwd)}})
    old = dict(os.environ)
    os.environ.update(env)  # the kernel inherits this process's environment
    try:
        client.execute()
    finally:
        os.environ.clear()
        os.environ.update(old)
    return nb


def _outputs(nb: object) -> str:
    text = []
    for c in nb.cells:
        for o in c.get("outputs", []):
            text.append(o.get("text", "") or str(o.get("data", {}).get("text/plain", "")))
    return "\n".join(text)


def test_notebooks_exist() -> None:
    assert [p.name for p in NOTEBOOKS] == ["figures_from_a_run.ipynb"]


@pytest.mark.parametrize("nb_path", NOTEBOOKS, ids=lambda p: p.stem)
def test_notebook_runs_from_its_folder(nb_path: Path, tmp_path: Path) -> None:
    before = sorted(p for p in REPO.rglob("*") if ".git" not in p.parts
                    and "__pycache__" not in p.parts and ".pytest_cache" not in p.parts)
    work = _working_copy(tmp_path / "repo")
    nb = _run(work / "docs" / "notebooks" / nb_path.name, work / "docs" / "notebooks",
              work / "tmp")
    out = _outputs(nb)
    # It found the working copy from docs/notebooks, and the study ran there.
    assert str(work) in out
    assert "[('B1', 'DH1')]" in out
    images = sum(1 for c in nb.cells for o in c.get("outputs", [])
                 if "image/png" in o.get("data", {}))
    assert images >= 8  # diagram, eigenvalues (x2), multipliers, shapes (x2), forces, modes (x2)
    assert any((work / "tmp").iterdir())  # the run went to the temporary folder
    after = sorted(p for p in REPO.rglob("*") if ".git" not in p.parts
                   and "__pycache__" not in p.parts and ".pytest_cache" not in p.parts)
    assert after == before  # nothing written into the checkout


def test_notebook_finds_files_from_repo_root(tmp_path: Path) -> None:
    # The set-up cell alone, from the root of the working copy: the same
    # checkout is found as from docs/notebooks.
    work = _working_copy(tmp_path / "repo")
    nb = _run(work / "docs" / "notebooks" / NOTEBOOKS[0].name, work, work / "tmp", cells=2)
    assert _outputs(nb).strip() == str(work.resolve())
