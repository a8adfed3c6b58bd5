# jerklab: the developer route (students: pip install "jerklab[lab]" and `jerklab lab`, see README).
# The targets call the `jerklab` command that `pip install -e .` puts in .venv/bin.
#   make lab    set up .venv and open JupyterLab on the repository's notebooks/ (virtual rig by default)
#   make test   set up .venv and run every test (unit, property, notebooks, firmware, browser)
#   make app    the standalone tuning page for a class (Voila, virtual rig) on http://127.0.0.1:8866/
#   make bench  print the benchmark tables and record them as JSON in benchmarks/results/
#   make book   static HTML of the executed notebooks and the API reference built from the docstrings
#               (build/book/html/index.html, api/index.html); reuses the notebooks make test executed
#               (build/executed/), Sphinx warnings are errors
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.jerklab-installed
PYTEST_ARGS ?=

.PHONY: setup lab test app bench book firmware clean

$(STAMP): environment.txt pyproject.toml setup.py
	@$(PYTHON) -c 'import sys; assert sys.version_info >= (3, 10), "jerklab needs Python 3.10 or newer, this is " + sys.version' 
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -r environment.txt
	$(BIN)/python -m pip install --quiet --no-deps -e .
	$(BIN)/python -m ipykernel install --sys-prefix --name python3 --display-name "Python 3 (jerklab)" > /dev/null
	touch $(STAMP)

setup: $(STAMP)

lab: setup
	$(BIN)/jerklab lab --no-copy notebooks/ $(LAB_ARGS)

test: setup
	$(BIN)/python -m pytest $(PYTEST_ARGS)

app: setup
	$(BIN)/jerklab app $(APP_ARGS)

bench: setup
	$(BIN)/python -m benchmarks

book: setup
	$(BIN)/python tools/build_book.py

firmware:
	$(MAKE) -C firmware

clean:
	rm -rf $(VENV) build dist *.egg-info artifacts
