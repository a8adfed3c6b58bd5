"""The book (make book): builds with Sphinx warnings as errors and shows every figure of docs/FIGURES.md.

Runs after tests/test_notebooks.py (tests/conftest.py orders it last), so the notebooks arrive
executed (build/executed/) and the build executes only those without outputs.
"""

from __future__ import annotations

import html
import pathlib
import re
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent
pytest.importorskip("myst_nb")
pytest.importorskip("schemdraw")


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


@pytest.mark.slow
def test_book_builds_and_shows_every_indexed_figure(tmp_path):
    out = tmp_path / "book"
    r = subprocess.run(
        [sys.executable, str(ROOT / "tools/build_book.py"), "--out", str(out)],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-6000:]
    print(r.stdout)
    html_dir = out / "html"
    pages = {}
    for p in (html_dir / "notebooks").glob("*.html"):
        text = html.unescape(p.read_text(encoding="utf-8"))
        # the diagrams are SVG files whose titles are text: search them with the page
        for src in re.findall(r'<img[^>]+src="([^"]+\.svg)"', text):
            text += (p.parent / src).resolve().read_text(encoding="utf-8")
        pages[p.stem] = text
    staged = out.parent / (out.name + "-src") / "notebooks"
    # every figure output of every notebook is an image on its page
    for nb in staged.glob("*.ipynb"):
        n = _figure_outputs(nb)
        assert pages[nb.stem].count("<img") >= n, (nb.name, n)
        assert n > 0, f"{nb.name} has no figure in the book"
    # every figure of the index is on the page the index names: by its full ID (headings, diagram
    # titles) or, for a figure a plot title carries, by its number on that paper's notebook
    for fig_id, nb in figure_index():
        if nb is None:
            continue
        text = pages[nb]
        short = re.sub(r"^(Stojčić|Xu & Meckl|Yang) ", "", fig_id)
        assert fig_id in text or fig_id.replace("&", "and") in text or short in text, (fig_id, nb)
