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
    expect = ([f"Stojčić Fig. {i}" for i in range(1, 8)] + [f"Xu & Meckl Fig. {i}" for i in range(1, 10)]
              + ["Xu & Meckl Table I", "Xu & Meckl Table II"] + [f"Yang Fig. {i}" for i in range(1, 10)])
    assert sorted(ids) == sorted(expect)


@pytest.mark.slow
def test_book_builds_and_shows_every_indexed_figure(tmp_path):
    out = tmp_path / "book"
    r = subprocess.run([sys.executable, str(ROOT / "tools/build_book.py"), "--out", str(out)],
                       capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-6000:]
    print(r.stdout)
    pages = {p.stem: p.read_text(encoding="utf-8") for p in (out / "html/notebooks").glob("*.html")}
    for fig_id, nb in figure_index():
        if nb is None:
            continue
        page = html.unescape(pages[nb])
        # the ID appears in a heading or a title of that page, and the page carries rendered images
        short = fig_id.replace("Xu & Meckl ", "").replace("Stojčić ", "").replace("Yang ", "")
        assert fig_id in page or (short in page and fig_id.split()[0] in page), (fig_id, nb)
        assert page.count("<img") >= 1, nb
    # every notebook page has its figures embedded as images (not missing outputs)
    for nb, text in pages.items():
        assert "<img" in text, nb
