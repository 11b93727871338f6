"""The notebooks in docs/notebooks run top to bottom (nbclient, kernel python3).

Each runs in a temporary working copy (the notebooks, the specs and the
stored run they read), from its ``docs/notebooks`` folder, with this
checkout's ``contfil`` on the kernel's path and ``TMPDIR`` inside the copy:
nothing is written into the checkout.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

if os.environ.get("CI"):
    # CI installs the test extras: a missing runner is a failure there, not a skip.
    import nbclient
    import nbformat
else:
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


def _files(root: Path) -> list[Path]:
    skip = {".git", "__pycache__", ".pytest_cache", ".ruff_cache"}
    return sorted(p for p in root.rglob("*") if not skip & set(p.parts))


@pytest.fixture(scope="module")
def executed(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, object, list[Path]]:
    """The notebook executed from ``docs/notebooks`` of a working copy (once
    per module: it runs the default study, about 30 s)."""
    before = _files(REPO)
    work = _working_copy(tmp_path_factory.mktemp("nb") / "repo")
    nb = _run(work / "docs" / "notebooks" / NOTEBOOKS[0].name, work / "docs" / "notebooks",
              work / "tmp")
    return work, nb, before


def test_notebook_runs_from_its_folder(executed: tuple[Path, object, list[Path]]) -> None:
    work, nb, before = executed
    out = _outputs(nb)
    # It found the working copy from docs/notebooks, and the study ran there.
    assert str(work) in out
    assert "[('B1', 'DH1')]" in out
    images = sum(1 for c in nb.cells for o in c.get("outputs", [])
                 if "image/png" in o.get("data", {}))
    # diagram, eigenvalues (default run, stored beating run), multipliers,
    # shapes (whirling, beating), force profiles, modes (critical, whirling)
    assert images == 9
    assert list((work / "tmp").glob("contfil_nb_*/default/graph.json"))
    assert _files(REPO) == before  # nothing written into the checkout


def test_notebook_finds_files_from_repo_root(tmp_path: Path) -> None:
    # The set-up cell alone, from the root of a working copy: the same
    # checkout is found as from docs/notebooks.
    work = _working_copy(tmp_path / "repo")
    nb = _run(work / "docs" / "notebooks" / NOTEBOOKS[0].name, work, work / "tmp", cells=2)
    assert _outputs(nb).strip() == str(work.resolve())


def _recipe_blocks() -> list[str]:
    text = (REPO / "docs" / "user-guide.md").read_text(encoding="utf-8")
    section = text[text.index("## In a notebook"):]
    section = section[: section.index("\n## ", 1)]
    return re.findall(r"```python\n(.*?)```", section, flags=re.S)


def test_user_guide_notebook_recipe_runs(executed: tuple[Path, object, list[Path]]) -> None:
    # The user guide's recipe, as a user would paste it in the repository
    # root after `contfil run branches/default.toml` (here: the notebook's
    # run of the same spec). The last block, run_study, is what the notebook
    # itself does first.
    work, _, _ = executed
    blocks = _recipe_blocks()
    assert len(blocks) == 3 and "run_study" in blocks[2]
    (work / "runs").mkdir()
    run = next((work / "tmp").glob("contfil_nb_*/default"))
    shutil.copytree(run, work / "runs" / "default")
    code = "\n".join(blocks[:2]) + "\nprint('recipe ok', g.connected('B0'), X.shape)\n"
    env = dict(os.environ, PYTHONPATH=str(REPO), MPLBACKEND="Agg")
    res = subprocess.run([sys.executable, "-c", code], cwd=work, env=env, capture_output=True,
                         text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    assert "recipe ok [('B1', 'DH1')] (11, 21, 3)" in res.stdout
