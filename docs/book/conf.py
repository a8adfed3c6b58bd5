# Sphinx + MyST-NB configuration of the jerklab book (`make book`); tools/build_book.py stages the sources.
project = "jerklab"
author = "jerklab contributors"
extensions = ["myst_nb"]
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
