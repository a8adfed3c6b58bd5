# Sphinx configuration of the jerklab book (`make book`): MyST-NB for the notebooks and Markdown pages,
# autodoc + numpydoc for the API reference; tools/build_book.py stages the sources (api/ generated).
import importlib.util

project = "jerklab"
author = "jerklab contributors"
extensions = ["myst_nb", "sphinx.ext.autodoc", "numpydoc"]
myst_enable_extensions = ["dollarmath", "amsmath"]
myst_heading_anchors = 3
# Execute every notebook, except those tools/build_book.py staged from build/executed/ (the copies
# tests/test_notebooks.py executed), which it marks {"mystnb": {"execution_mode": "off"}}: a book built
# after the tests executes nothing twice; a new notebook (a lab) is executed here.
nb_execution_mode = "force"
nb_execution_timeout = 120
nb_execution_raise_on_error = True
nb_merge_streams = True
exclude_patterns = [
    "_build",
    "**.ipynb_checkpoints",
    "data/**",
]  # data/ is linked for the notebooks, not a page
html_theme = "alabaster"
html_title = "jerklab: jerk-controlled positioning"
# links from the Markdown pages into the repository (firmware/, data/ ...) are not pages of the book
suppress_warnings = ["myst.xref_missing", "myst.header"]
# A static page has no kernel: show a widget's PNG snapshot (the panels render one) instead of an
# empty widget view.
nb_mime_priority_overrides = [
    ("html", "application/vnd.jupyter.widget-view+json", None)
]  # None: never

# --- the API reference (api/, one page per public module, written by tools/build_book.py)
autodoc_member_order = "bysource"
autodoc_typehints = "signature"
autodoc_preserve_defaults = True  # show `Ts=paper.TS` as written, not its value
# jerklab imports these only inside the functions that need them; a build without one of them
# still imports every module, and autodoc documents it against a stand-in
_OPTIONAL = (
    "numba",
    "ruckig",
    "schemdraw",
    "ipywidgets",
    "voila",
    "otter",
    "jupyterhub",
    "serial",
    "tqdm",
    "psutil",
    "nbformat",
    "nbclient",
    "playwright",
)
autodoc_mock_imports = [m for m in _OPTIONAL if importlib.util.find_spec(m) is None]
numpydoc_show_class_members = False  # autodoc lists the members; numpydoc renders the sections
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False
numpydoc_validation_checks = set()

# The docstrings of these modules still write an absolute value |x| in running text, which
# reStructuredText reads as a substitution reference; until they are rewritten as ``|x|`` (as the
# rest of the package is), the reference shows such a |x| as a literal. Nothing else is changed.
_PLAIN_BARS = ("jerklab.ident", "jerklab.lab")
_BAR = __import__("re").compile(r"(?<![|`\w])\|([^|\n`]{1,40}?)\|(?![|`_\w])")


def _literal_bars(app, what, name, obj, options, lines):
    if not name.startswith(_PLAIN_BARS):
        return
    for k, line in enumerate(lines):
        parts = line.split("``")
        parts[::2] = [_BAR.sub(r"``|\1|``", p) for p in parts[::2]]
        lines[k] = "``".join(parts)


def setup(app):
    app.connect("autodoc-process-docstring", _literal_bars, priority=400)
