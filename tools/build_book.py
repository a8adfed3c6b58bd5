"""Stage and build the jerklab book (``make book``): static HTML of the executed notebooks.

Sources are staged in ``build/book-src``: ``docs/book/index.md``, README.md, docs/FIGURES.md,
docs/THEORY.md, ``notebooks/*.ipynb`` and ``notebooks/labs/**``. A notebook that
tests/test_notebooks.py already executed (``build/executed/NAME``, newer than the source) is staged
with its outputs and marked not to execute; MyST-NB executes the others (``nb_execution_mode =
"force"``), in their staged folder, with ``data/`` linked beside ``notebooks/``. Sphinx runs
with warnings as errors. Prints the build time.

    python tools/build_book.py [--out build/book] [--executed build/executed]
"""

from __future__ import annotations

import argparse
import pathlib
import shutil
import subprocess
import sys
import time

import nbformat

ROOT = pathlib.Path(__file__).resolve().parent.parent
# every page under notebooks/labs/ (notebooks and Markdown), at any depth
LABS_TOCTREE = """
```{toctree}
:caption: Labs
:maxdepth: 1
:glob:

notebooks/labs/**
```
"""


def stage(src: pathlib.Path, executed: pathlib.Path) -> dict:
    if src.exists():
        shutil.rmtree(src)
    (src / "docs").mkdir(parents=True)
    index = (ROOT / "docs/book/index.md").read_text(encoding="utf-8")
    if any((ROOT / "notebooks/labs").glob("**/*.ipynb")):
        index += LABS_TOCTREE
    (src / "index.md").write_text(index, encoding="utf-8")
    shutil.copy2(ROOT / "README.md", src / "README.md")
    for name in ("FIGURES.md", "THEORY.md"):
        shutil.copy2(ROOT / "docs" / name, src / "docs" / name)
    reused, fresh = [], []
    nbdir = ROOT / "notebooks"
    for nb in sorted(list(nbdir.glob("*.ipynb")) + list(nbdir.glob("labs/**/*.ipynb"))):
        if ".ipynb_checkpoints" in nb.parts:
            continue
        rel = nb.relative_to(ROOT)
        dest = src / rel
        dest.parent.mkdir(parents=True, exist_ok=True)
        done = executed / nb.name
        if nb.parent == nbdir and done.exists() and done.stat().st_mtime >= nb.stat().st_mtime:
            book = nbformat.read(done, as_version=4)
            book.metadata["mystnb"] = {"execution_mode": "off"}  # executed by the tests already
            nbformat.write(book, dest)
            reused.append(nb.name)
        elif "labs" in rel.parts:
            # the lab worksheets are shown as handed out (answers blank, checks not run): executing
            # them here would only show failing checks; tests/test_labs.py runs their masters
            book = nbformat.read(nb, as_version=4)
            book.metadata["mystnb"] = {"execution_mode": "off"}
            nbformat.write(book, dest)
            reused.append(str(rel))
        else:
            shutil.copy2(nb, dest)
            fresh.append(str(rel))
    (src / "data").symlink_to(ROOT / "data", target_is_directory=True)  # notebooks read ../data
    labs = nbdir / "labs"
    if labs.is_dir():  # the labs' data files and Markdown pages
        for f in labs.rglob("*"):
            if f.is_file() and f.suffix != ".ipynb" and ".ipynb_checkpoints" not in f.parts:
                d = src / f.relative_to(ROOT)
                d.parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(f, d)
    return {"reused": reused, "executed": fresh}


def build(out: pathlib.Path, executed: pathlib.Path) -> float:
    t0 = time.perf_counter()
    src = out.parent / (out.name + "-src")
    info = stage(src, executed)
    print(
        f"book: {len(info['reused'])} notebooks not executed (outputs from the tests, or lab worksheets), "
        f"{len(info['executed'])} to execute: {', '.join(info['executed']) or '-'}",
        flush=True,
    )
    cmd = [
        sys.executable,
        "-m",
        "sphinx",
        "-W",
        "--keep-going",
        "-q",
        "-b",
        "html",
        "-c",
        str(ROOT / "docs/book"),
        str(src),
        str(out / "html"),
    ]
    subprocess.run(cmd, check=True, cwd=ROOT / "notebooks")
    dt = time.perf_counter() - t0
    print(f"book: built {out / 'html' / 'index.html'} in {dt:.1f} s")
    return dt


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "build/book"))
    ap.add_argument("--executed", default=str(ROOT / "build/executed"))
    a = ap.parse_args(argv)
    build(pathlib.Path(a.out), pathlib.Path(a.executed))


if __name__ == "__main__":
    main()
