"""Stage and build the jerklab book (``make book``): the executed notebooks and the API reference.

Sources are staged in ``build/book-src``: ``docs/book/index.md``, README.md, docs/FIGURES.md,
docs/THEORY.md, docs/INTERFACES.md, ``notebooks/*.ipynb``, ``notebooks/labs/**`` and ``api/``, the
API reference: one page per public module of the package, found by walking ``jerklab`` (every
module and subpackage whose dotted name has no part starting with ``_``), so a new module or a
module that becomes a package gets its page without editing a list. Each page documents, with
Sphinx autodoc and numpydoc, the names the module defines (its ``__all__`` when it has one, else
its public top-level names) and links the names it re-exports to the page that defines them. A
notebook that
tests/test_notebooks.py already executed (``build/executed/NAME``, newer than the source) is staged
with its outputs and marked not to execute; MyST-NB executes the others (``nb_execution_mode =
"force"``), in their staged folder, with ``data/`` linked beside ``notebooks/``. Sphinx runs
with warnings as errors. Prints the build time.

    python tools/build_book.py [--out build/book] [--executed build/executed]
"""

from __future__ import annotations

import argparse
import ast
import importlib
import importlib.util
import inspect
import os
import pathlib
import pkgutil
import re
import shutil
import subprocess
import sys
import time

import nbformat

ROOT = pathlib.Path(__file__).resolve().parent.parent
PACKAGE = "jerklab"
# every page under notebooks/labs/ (notebooks and Markdown), at any depth
LABS_TOCTREE = """
```{toctree}
:caption: Labs
:maxdepth: 1
:glob:

notebooks/labs/**
```
"""


def public_modules(package: str = PACKAGE) -> list[str]:
    """Every public module of ``package``: the package, its modules and subpackages at any depth,
    skipping names with a part that starts with ``_`` (private modules, ``__main__``)."""

    def fail(name):
        raise ImportError(f"cannot import {name} to document it")

    pkg = importlib.import_module(package)
    names = [package]
    for info in pkgutil.walk_packages(pkg.__path__, package + ".", onerror=fail):
        if not any(part.startswith("_") for part in info.name.split(".")[1:]):
            names.append(info.name)
    return sorted(names)


def _top_level_assignments(module) -> set[str]:
    """Names a module's own source assigns at the top level (its data, not what it imports)."""
    try:
        tree = ast.parse(inspect.getsource(module))
    except (OSError, TypeError):
        return set()
    out = set()
    for node in tree.body:
        targets = (
            node.targets
            if isinstance(node, ast.Assign)
            else [node.target]
            if isinstance(node, (ast.AnnAssign, ast.AugAssign))
            else []
        )
        for t in targets:
            for n in ast.walk(t):
                if isinstance(n, ast.Name):
                    out.add(n.id)
    return out


def module_members(modname: str, documented: set[str]) -> tuple[list[str], list[tuple[str, str]]]:
    """``(own, reexported)`` names of a public module.

    ``own``: what its page documents -- the classes and functions it defines (or that a private
    module defines and its ``__all__`` publishes) and the data its source assigns; ``reexported``:
    ``(name, home)`` for names defined by another public module ``home`` in ``documented``.
    """
    mod = importlib.import_module(modname)
    listed = getattr(mod, "__all__", None)
    names = list(listed) if listed is not None else sorted(n for n in vars(mod) if n[0] != "_")
    data = _top_level_assignments(mod)
    own, reexported = [], []
    for name in names:
        if name.startswith("__") or not hasattr(mod, name):
            continue
        obj = getattr(mod, name)
        if inspect.ismodule(obj):
            continue
        home = getattr(obj, "__module__", None) if (inspect.isclass(obj) or callable(obj)) else None
        if home is None:
            if name in data or listed is not None:
                own.append(name)
        elif home == modname:
            own.append(name)
        elif home.split(".")[0] == modname.split(".")[0]:
            if home in documented and name in vars(importlib.import_module(home)):
                reexported.append((name, home))
            elif home not in documented and listed is not None:
                own.append(name)  # defined in a private module, published by this __all__
    return own, reexported


def _first_line(modname: str) -> str:
    doc = inspect.getdoc(importlib.import_module(modname)) or ""
    return doc.strip().splitlines()[0].rstrip(".:") if doc.strip() else ""


def _rst_title(text: str) -> str:
    return f"{text}\n{'=' * len(text)}\n"


def stage_api(src: pathlib.Path, package: str = PACKAGE) -> list[str]:
    """Write ``src/api/``: ``index.rst`` and one page per public module. Returns the modules."""
    api = src / "api"
    api.mkdir(parents=True, exist_ok=True)
    modules = public_modules(package)
    documented = set(modules)
    for modname in modules:
        own, reexported = module_members(modname, documented)
        lines = [_rst_title(modname), f".. automodule:: {modname}", ""]
        if reexported:
            lines += [
                ".. rubric:: Also importable from here",
                "",
                *(f"* ``{n}``: :py:obj:`{home}.{n}`" for n, home in reexported),
                "",
            ]
        if own:
            lines += [f".. currentmodule:: {modname}", ""]
            for name in own:
                kind = _kind(modname, name)
                lines += [f".. auto{kind}:: {name}"]
                if kind in ("class", "exception"):
                    lines += ["   :members:", "   :show-inheritance:"]
                lines.append("")
        (api / f"{modname}.rst").write_text("\n".join(lines), encoding="utf-8")
    sections: dict[str, list[str]] = {}
    for modname in modules:
        parts = modname.split(".")
        key = ".".join(parts[:2]) if len(parts) > 2 else package
        if importlib.util.find_spec(modname).submodule_search_locations and len(parts) == 2:
            key = modname
        sections.setdefault(key, []).append(modname)
    index = [
        _rst_title("API reference"),
        "Built from the docstrings (numpydoc) of every public module of the package; the",
        ":doc:`contracts <../docs/INTERFACES>` between the modules (protocol, file formats, units,",
        "layers) are on a page of their own.",
        "",
        ".. toctree::",
        "   :hidden:",
        "",
        *(f"   {m}" for m in modules),
        "",
    ]
    for key, mods in sections.items():
        index += [f".. rubric:: {key}", ""]
        index += [f"* :doc:`{m}` -- {_first_line(m)}" for m in mods]
        index.append("")
    (api / "index.rst").write_text("\n".join(index), encoding="utf-8")
    return modules


def _kind(modname: str, name: str) -> str:
    obj = getattr(importlib.import_module(modname), name)
    if inspect.isclass(obj):
        return "exception" if issubclass(obj, BaseException) else "class"
    if inspect.isfunction(obj) or inspect.isbuiltin(obj) or callable(obj):
        return "function"
    return "data"


#: a Markdown link from docs/ to a module's source: ``(../jerklab/rig/client.py)``, ``(../jerklab/rig/)``
_SOURCE_LINK = re.compile(r"\]\(\.\./(jerklab(?:/[A-Za-z0-9_]+)*)(?:\.py|/|/__init__\.py)\)")


def api_links(text: str) -> str:
    """Point the links of a docs/ page at a module's source to the module's API page instead (the
    source links serve a reader of the repository, the API pages a reader of the book)."""
    return _SOURCE_LINK.sub(lambda m: f"](../api/{m.group(1).replace('/', '.')}.rst)", text)


def stage(src: pathlib.Path, executed: pathlib.Path) -> dict:
    if src.exists():
        shutil.rmtree(src)
    (src / "docs").mkdir(parents=True)
    index = (ROOT / "docs/book/index.md").read_text(encoding="utf-8")
    if any((ROOT / "notebooks/labs").glob("**/*.ipynb")):
        index += LABS_TOCTREE
    (src / "index.md").write_text(index, encoding="utf-8")
    shutil.copy2(ROOT / "README.md", src / "README.md")
    for name in ("FIGURES.md", "THEORY.md", "INTERFACES.md"):
        text = (ROOT / "docs" / name).read_text(encoding="utf-8")
        (src / "docs" / name).write_text(api_links(text), encoding="utf-8")
    modules = stage_api(src)
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
    return {"reused": reused, "executed": fresh, "modules": modules}


def build(out: pathlib.Path, executed: pathlib.Path) -> float:
    t0 = time.perf_counter()
    src = out.parent / (out.name + "-src")
    info = stage(src, executed)
    print(
        f"book: {len(info['reused'])} notebooks not executed (outputs from the tests, or lab worksheets), "
        f"{len(info['executed'])} to execute: {', '.join(info['executed']) or '-'}; "
        f"API reference of {len(info['modules'])} modules",
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
    # the kernels MyST-NB starts draw inline: a non-interactive MPLBACKEND (Agg, as a test
    # run or a headless shell sets it) would make plt.show() draw nothing and leave the pages
    # without their figures
    env = {k: v for k, v in os.environ.items() if k != "MPLBACKEND"}
    subprocess.run(cmd, check=True, cwd=ROOT / "notebooks", env=env)
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
