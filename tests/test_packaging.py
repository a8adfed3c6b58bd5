"""The package a student installs: sdist and wheel built (python -m build), checked (twine check),
then the wheel installed into a fresh virtual environment that cannot see the clone, and the
student path run there (import, ``jerklab --version``, ``jerklab lab --copy-only``, the virtual rig
recording to the working folder, two notebooks executed from the working folder).

The fresh environment sees the shared environment's installed packages through a ``.pth`` line
(its site-packages directory only: the shared environment's editable jerklab is not loaded) and
installs only the built wheel with ``--no-index``, so the test is offline and about 1–2 minutes.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from email.parser import Parser
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.slow

#: never in a student's install, not even with the [lab] extra
DEV_ONLY = {"pytest", "pytest-xdist", "hypothesis", "playwright", "ruckig", "build", "twine"}
_IGNORE = shutil.ignore_patterns(
    ".git",
    ".venv",
    "build",
    "dist",
    "*.egg-info",
    "artifacts",
    "__pycache__",
    ".ipynb_checkpoints",
    ".pytest_cache",
    ".hypothesis",
    "recordings",
    "lab-work",
    "handin",
    "*.elf",
    "*.o",
    "*.hex",
    "*.vvp",
    "*.vcd",
)


def _run(cmd, **kw):
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=kw.pop("timeout", 300), **kw)
    assert r.returncode == 0, f"{cmd}\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"
    return r


def _clean_env(**extra):
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("PYTHONPATH", "VIRTUAL_ENV", "PYTHONHOME") and not k.startswith("JERKLAB_")
    }
    env.update(extra)
    return env


@pytest.fixture(scope="module")
def dists(tmp_path_factory):
    """sdist and wheel built from a copy of the source tree (the clone stays untouched)."""
    pytest.importorskip("build")
    pytest.importorskip("twine")
    tmp = tmp_path_factory.mktemp("pkg")
    src = tmp / "src"
    shutil.copytree(ROOT, src, ignore=_IGNORE)
    out = tmp / "dist"
    # --no-isolation: the shared environment's setuptools and wheel, no download
    _run([sys.executable, "-m", "build", "--no-isolation", "--outdir", str(out), str(src)], cwd=tmp)
    (wheel,) = out.glob("jerklab-*.whl")
    (sdist,) = out.glob("jerklab-*.tar.gz")
    return tmp, wheel, sdist


def test_twine_check_passes(dists):
    _, wheel, sdist = dists
    r = _run([sys.executable, "-m", "twine", "check", "--strict", str(wheel), str(sdist)])
    assert r.stdout.count("PASSED") == 2


def test_wheel_has_every_module_and_the_student_files(dists):
    _, wheel, _ = dists
    names = set(zipfile.ZipFile(wheel).namelist())
    modules = {p.relative_to(ROOT).as_posix() for p in (ROOT / "jerklab").rglob("*.py")}
    assert modules - names == set(), "the wheel misses these modules (setup.py packages)"
    for folder in ("notebooks", "data", "app"):
        shipped = {
            f"jerklab/_share/{p.relative_to(ROOT / folder).as_posix()}".replace(
                "jerklab/_share/", f"jerklab/_share/{folder}/", 1
            )
            for p in (ROOT / folder).rglob("*")
            if p.is_file() and ".ipynb_checkpoints" not in p.parts and "__pycache__" not in p.parts
        }
        assert shipped and shipped - names == set(), folder
    assert not any(n.startswith(("tests/", "firmware/", "benchmarks/")) for n in names)


def test_lab_extra_has_no_test_tools(dists):
    _, wheel, _ = dists
    with zipfile.ZipFile(wheel) as z:
        (meta_name,) = [n for n in z.namelist() if n.endswith(".dist-info/METADATA")]
        meta = Parser().parsestr(z.read(meta_name).decode())
    reqs = meta.get_all("Requires-Dist")
    student = [r for r in reqs if "extra ==" not in r or 'extra == "lab"' in r]
    names = {
        r.split(";")[0].split(">")[0].split("=")[0].split("[")[0].strip().lower() for r in student
    }
    assert {"jupyterlab", "voila", "ipykernel", "pyserial"} <= names
    assert names & DEV_ONLY == set(), names & DEV_ONLY
    assert (
        meta["Name"] == "jerklab" and "jerklab" in meta.get_payload()[:2000]
    )  # README as description


def test_lab_extra_pulls_no_test_tools_transitively(dists):
    """The whole dependency tree of jerklab[lab], resolved on this environment's installed
    distributions: no test tool; Playwright's Python package only through nbconvert[webpdf]."""
    from importlib import metadata

    from packaging.requirements import Requirement

    _, wheel, _ = dists
    with zipfile.ZipFile(wheel) as z:
        (meta_name,) = [n for n in z.namelist() if n.endswith(".dist-info/METADATA")]
        reqs = Parser().parsestr(z.read(meta_name).decode()).get_all("Requires-Dist")
    direct = {
        Requirement(r).name.lower()
        for r in reqs
        if Requirement(r).marker is None or Requirement(r).marker.evaluate({"extra": "lab"})
    }
    todo = [(Requirement(r), "lab", "jerklab[lab]") for r in reqs]
    seen, missing, via = {}, [], {}
    while todo:
        req, extra, parent = todo.pop()
        if req.marker is not None and not req.marker.evaluate({"extra": extra}):
            continue
        name = req.name.lower().replace("_", "-")
        key = (name, tuple(sorted(req.extras)))
        if key in seen:
            continue
        seen[key] = True
        via.setdefault(name, set()).add(parent)
        try:
            dist = metadata.distribution(name)
        except metadata.PackageNotFoundError:
            missing.append(name)
            continue
        for r in dist.requires or []:
            sub = Requirement(r)
            for e in req.extras or {""}:
                todo.append((sub, e, name))
    names = {n for n, _ in seen}
    # no test tool, no browser driver, and no grader: the worksheets' checks run without otter
    assert names & (DEV_ONLY | {"otter-grader"}) == set(), sorted(
        names & (DEV_ONLY | {"otter-grader"})
    )
    assert direct & DEV_ONLY == set()
    assert {"jupyterlab", "voila", "numpy"} <= names and not missing, missing


def test_student_path_in_a_fresh_environment(dists):
    tmp, wheel, _ = dists
    venv = tmp / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", str(venv)])
    bindir = venv / ("Scripts" if os.name == "nt" else "bin")
    py = bindir / ("python.exe" if os.name == "nt" else "python")
    purelib = _run(
        [str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"]
    ).stdout.strip()
    shared = {sysconfig.get_paths()[k] for k in ("purelib", "platlib")}
    (Path(purelib) / "_shared_env.pth").write_text("".join(f"{p}\n" for p in sorted(shared)))
    home = tmp / "student"
    home.mkdir()
    env = _clean_env(JERKLAB_HOME=str(home / "jerklab"), MPLBACKEND="Agg")
    _run(
        [
            str(py),
            "-m",
            "pip",
            "install",
            "--quiet",
            "--no-index",
            "--no-build-isolation",
            f"{wheel}[lab]",
        ],
        cwd=home,
        env=env,
    )

    where = _run(
        [
            str(py),
            "-c",
            "import jerklab, jerklab.resources as r; print(jerklab.__file__); "
            "print(r.share_path('notebooks'))",
        ],
        cwd=home,
        env=env,
    ).stdout.split()
    assert all(Path(w).is_relative_to(venv) for w in where), where  # not the clone, not /work/main
    assert Path(where[1]).name == "notebooks" and "_share" in where[1]

    r = _run([str(bindir / "jerklab"), "--version"], cwd=home, env=env)
    assert r.stdout.strip() == "jerklab 0.1.0"

    r = _run([str(bindir / "jerklab"), "lab", "--copy-only"], cwd=home, env=env)
    work = home / "jerklab"
    assert (work / "notebooks" / "02_identification.ipynb").is_file(), r.stdout
    assert (work / "data" / "ident" / "step_6V.csv").is_file()

    script = home / "student_path.py"  # a copy: the clone's tests/ is not on the path
    shutil.copyfile(ROOT / "tests" / "_student_path.py", script)
    r = _run([str(py), str(script), str(home)], cwd=home, env=env)
    assert "STUDENT PATH OK" in r.stdout, r.stdout
    assert list((home / "recordings").glob("*_move.csv")), (
        "the rig recorded into the working folder"
    )

    # a notebook run where the student opens it (02 reads ../data/ident relative to itself; the
    # suite runs every notebook from the clone, tests/test_notebooks.py)
    run_nb = (
        "import sys, nbformat; from nbclient import NotebookClient\n"
        "for p in sys.argv[1:]:\n"
        "    nb = nbformat.read(p, as_version=4)\n"
        "    here = str(__import__('pathlib').Path(p).parent)\n"
        "    NotebookClient(nb, timeout=120, kernel_name='python3',\n"
        "                   resources={'metadata': {'path': here}}).execute()\n"
        "    print('ran', p)\n"
    )
    nbs = [str(work / "notebooks" / "02_identification.ipynb")]
    r = _run([str(py), "-c", run_nb, *nbs], cwd=home, env=env, timeout=400)
    assert r.stdout.count("ran ") == 1
    # the notebooks ran on the installed package: no file of the clone was written
    assert not any((ROOT / "notebooks").glob("recordings"))
    assert json.loads((work / "notebooks" / "02_identification.ipynb").read_text())["cells"]
