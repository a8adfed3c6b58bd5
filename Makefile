# jerklab: the developer route (students: pip install "jerklab[lab]" and `jerklab lab`, see README).
# The targets call the `jerklab` command that `pip install -e .` puts in .venv/bin.
#   make lab    set up .venv and open JupyterLab on the repository's notebooks/ (virtual rig by default)
#   make test   set up .venv and run every test (unit, property, notebooks, firmware, browser) in
#               parallel (pytest-xdist, JOBS workers); what .ci/run calls
#   make check  the fast tier: the tests that need no notebook kernel, browser, hub, simavr, firmware
#               build, Arduino IDE or package build (markers: tests/conftest.py FILE_MARKS)
#   make lint   ruff check and ruff format --check on the whole tree (.ci/run runs it first)
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
# one worker more than cores: about a third of the suite waits (real-time rig runs, servers,
# browsers, kernels starting) and a third worker fills it (21.8 min against 24.8 with two, same load)
JOBS   ?= $(shell $(PYTHON) -c 'import os; print((os.cpu_count() or 1) + 1)')
# the groups of tests/conftest.py ONE_WORKER stay on one worker (--dist loadgroup)
XDIST  := -n $(JOBS) --dist loadgroup
CHECK_MARKS := not (notebook or book or browser or hub or simavr or firmware or arduino or packaging or slow)

.PHONY: setup lab test check lint app bench book firmware clean

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
	$(BIN)/python -m pytest $(XDIST) $(PYTEST_ARGS)

check: setup
	$(BIN)/python -m pytest $(XDIST) -m "$(CHECK_MARKS)" $(PYTEST_ARGS)

lint: setup
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

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
