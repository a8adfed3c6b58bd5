# Sphinx + MyST-NB configuration of the jerklab book (`make book`); tools/build_book.py stages the sources.
project = "jerklab"
author = "jerklab contributors"
extensions = ["myst_nb"]
myst_enable_extensions = ["dollarmath", "amsmath"]
myst_heading_anchors = 3
# "auto": execute only notebooks that arrive without outputs. tools/build_book.py stages the notebooks
# that tests/test_notebooks.py already executed (build/executed/), so a book built after the tests
# executes nothing twice; any other notebook (a new lab) is executed here.
nb_execution_mode = "auto"
nb_execution_timeout = 120
nb_execution_raise_on_error = True
nb_merge_streams = True
exclude_patterns = ["_build", "**.ipynb_checkpoints"]
html_theme = "alabaster"
html_title = "jerklab: jerk-controlled positioning"
# links from the Markdown pages into the repository (firmware/, data/ ...) are not pages of the book
suppress_warnings = ["myst.xref_missing", "myst.header"]
