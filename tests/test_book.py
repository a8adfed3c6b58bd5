"""The book (make book): builds with Sphinx warnings as errors, shows every figure of
docs/FIGURES.md, and carries the API reference: a page per public module, found by walking the
package, with the numpydoc sections of the docstrings rendered.

Runs after tests/test_notebooks.py (tests/conftest.py orders it last), so the notebooks arrive
executed (build/executed/) and the build executes only those without outputs.
"""

from __future__ import annotations

import html
import importlib.util
import pathlib
import re
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent
pytest.importorskip("myst_nb")
pytest.importorskip("schemdraw")
pytest.importorskip("numpydoc")

_spec = importlib.util.spec_from_file_location("build_book", ROOT / "tools/build_book.py")
build_book = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(build_book)


def package_modules(root: pathlib.Path, package: str) -> set[str]:
    """The public modules of a package read from its files (not by the builder's walk): every
    ``.py`` file of a regular package (each folder on the way has an ``__init__.py``) whose dotted
    name has no part starting with ``_``."""
    names = set()
    for f in (root / package).rglob("*.py"):
        rel = f.relative_to(root)
        if not all(
            (root.joinpath(*rel.parts[:i]) / "__init__.py").exists()
            for i in range(1, len(rel.parts))
        ):
            continue
        parts = rel.with_suffix("").parts
        parts = parts[:-1] if parts[-1] == "__init__" else parts
        if not any(p.startswith("_") for p in parts[1:]):
            names.add(".".join(parts))
    return names


def figure_index():
    """(ID, notebook file or None) of every row of docs/FIGURES.md."""
    rows = []
    for line in (ROOT / "docs/FIGURES.md").read_text(encoding="utf-8").splitlines():
        m = re.match(r"\| ((?:Stojčić|Xu & Meckl|Yang) (?:Fig\.|Table) [IVX0-9]+) \|", line)
        if m:
            nb = re.search(r"\]\(\.\./notebooks/(\d\d_[a-z_]+)\.ipynb\)", line.split("|")[3])
            reproduced = not line.split("|")[3].strip().startswith("not reproduced")
            rows.append((m.group(1), nb.group(1) if (nb and reproduced) else None))
    return rows


def test_index_lists_every_figure_of_the_papers():
    ids = [r[0] for r in figure_index()]
    expect = (
        [f"Stojčić Fig. {i}" for i in range(1, 8)]
        + [f"Xu & Meckl Fig. {i}" for i in range(1, 10)]
        + ["Xu & Meckl Table I", "Xu & Meckl Table II"]
        + [f"Yang Fig. {i}" for i in range(1, 10)]
    )
    assert sorted(ids) == sorted(expect)


def _figure_outputs(nb_path):
    import nbformat

    nb = nbformat.read(nb_path, as_version=4)
    return sum(
        1
        for c in nb.cells
        if c.cell_type == "code"
        for o in c.get("outputs", [])
        if "image/png" in o.get("data", {}) or "image/svg+xml" in o.get("data", {})
    )


def test_the_api_pages_come_from_the_package_not_a_list(tmp_path, monkeypatch):
    """A module added to a package gets its page, a private one none; a subpackage's modules are
    found; a name a module re-exports is linked to the page that defines it, not documented twice."""
    pkg = tmp_path / "fakepkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text(
        '"""Fake."""\nfrom ._hidden import helper\nfrom .alpha import f\n__all__ = ["f", "helper"]\n'
    )
    (pkg / "alpha.py").write_text(
        '"""Alpha.\n\nMore."""\nLIMIT = 3\n\ndef f(x):\n    """F.\n\n    Parameters\n'
        '    ----------\n    x : float\n        The x.\n    """\n\nclass C:\n    """C."""\n'
    )
    (pkg / "_hidden.py").write_text('"""Private."""\n\ndef helper():\n    """Help."""\n')
    (pkg / "sub" / "__init__.py").write_text('"""Sub."""\n')
    (pkg / "sub" / "beta.py").write_text(
        '"""Beta."""\nimport math\nfrom .._hidden import helper\nfrom ..alpha import C\n'
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    src = tmp_path / "src"
    mods = build_book.stage_api(src, package="fakepkg")
    expect = {"fakepkg", "fakepkg.alpha", "fakepkg.sub", "fakepkg.sub.beta"}
    assert set(mods) == expect == package_modules(tmp_path, "fakepkg")
    pages = {p.stem: p.read_text() for p in (src / "api").glob("*.rst")}
    assert set(pages) == expect | {"index"}
    alpha = pages["fakepkg.alpha"]
    assert ".. autofunction:: f" in alpha and ".. autoclass:: C" in alpha
    assert ".. autodata:: LIMIT" in alpha
    # re-exports link to the defining page; imports of other libraries are not documented
    top, beta = pages["fakepkg"], pages["fakepkg.sub.beta"]
    assert ":py:obj:`fakepkg.alpha.f`" in top and ".. autofunction:: f" not in top
    assert ":py:obj:`fakepkg.alpha.C`" in beta and "math" not in beta and "helper" not in beta
    # a private module's function is documented where an __all__ publishes it, and only there
    assert ".. autofunction:: helper" in top
    for m in expect:
        assert f":doc:`{m}`" in pages["index"]


def test_every_public_module_of_jerklab_gets_a_page(tmp_path):
    mods = build_book.stage_api(tmp_path)
    assert set(mods) == package_modules(ROOT, "jerklab")
    for m in ("jerklab.planner", "jerklab.ident", "jerklab.rig.client", "jerklab.lab.session"):
        assert m in mods
    assert not any(part.startswith("_") for m in mods for part in m.split(".")[1:])


@pytest.fixture(scope="module")
def book(tmp_path_factory):
    out = tmp_path_factory.mktemp("book") / "book"
    r = subprocess.run(
        [sys.executable, str(ROOT / "tools/build_book.py"), "--out", str(out)],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-6000:]
    print(r.stdout)
    return out


#: functions whose numpydoc Parameters (and the names in it) the API reference must render
DOCUMENTED = {
    "jerklab.planner.plan_sine_jerk": ("distance", "max_jerk, max_accel, max_velocity"),
    "jerklab.sim.simulate": ("profile", "motor", "controller", "settle_band"),
    "jerklab.controller.discrete_pole_placement_pid": ("K, tau", "extra_pole"),
}


@pytest.mark.slow
def test_book_has_an_api_page_for_every_public_module(book):
    api = book / "html" / "api"
    modules = package_modules(ROOT, "jerklab")
    missing = sorted(m for m in modules if not (api / f"{m}.html").exists())
    assert missing == []
    index = (api / "index.html").read_text(encoding="utf-8")
    assert all(f'href="{m}.html"' in index for m in modules)
    for name, params in DOCUMENTED.items():
        module = name.rsplit(".", 1)[0]
        page = (api / f"{module}.html").read_text(encoding="utf-8")
        start = page.index(f'id="{name}"')
        end = page.find("</dl>\n</dd></dl>", start)
        entry = html.unescape(re.sub(r"<[^>]+>", "", page[start : end if end > 0 else None]))
        assert "Parameters:" in entry, name
        for p in params:
            assert p in entry, (name, p)
    # the contracts page is in the book and links into the reference
    contracts = (book / "html" / "docs" / "INTERFACES.html").read_text(encoding="utf-8")
    assert "../api/jerklab.protocol.html" in contracts


@pytest.mark.slow
def test_book_builds_and_shows_every_indexed_figure(book):
    out = book
    html_dir = out / "html"
    pages = {}
    for p in (html_dir / "notebooks").glob("*.html"):
        text = html.unescape(p.read_text(encoding="utf-8"))
        # the diagrams are SVG files whose titles are text: search them with the page
        for src in re.findall(r'<img[^>]+src="([^"]+\.svg)"', text):
            text += (p.parent / src).resolve().read_text(encoding="utf-8")
        pages[p.stem] = text
    staged = out.parent / (out.name + "-src") / "notebooks"
    # every figure output of every notebook is an image on its page (a notebook staged with the
    # tests' outputs: at least as many images as it has figures; one the build executed itself,
    # when the book is built alone, has no outputs staged: its page has images all the same)
    for nb in staged.glob("*.ipynb"):
        n = _figure_outputs(nb)
        imgs = pages[nb.stem].count("<img")
        assert imgs >= n, (nb.name, n)
        assert imgs > 0, f"{nb.name} has no figure in the book"
    # every figure of the index is on the page the index names: by its full ID (headings, diagram
    # titles) or, for a figure a plot title carries, by its number on that paper's notebook
    for fig_id, nb in figure_index():
        if nb is None:
            continue
        text = pages[nb]
        short = re.sub(r"^(Stojčić|Xu & Meckl|Yang) ", "", fig_id)
        assert fig_id in text or fig_id.replace("&", "and") in text or short in text, (fig_id, nb)
