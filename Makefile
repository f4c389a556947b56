# Two commands matter: `make demo` and `make test`. Both build .venv from nothing when it is missing.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

export VTK_DEFAULT_OPENGL_WINDOW ?= vtkEGLRenderWindow

.PHONY: all test demo bench evaluate compare mutants lint clean

all: test

$(STAMP): requirements-lock.txt pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --disable-pip-version-check -r requirements-lock.txt
	$(BIN)/python -m pip install --quiet --disable-pip-version-check --no-deps -e .
	touch $(STAMP)

test: $(STAMP)
	$(BIN)/python -m pytest -q

demo: $(STAMP)
	$(BIN)/isosimtf phantom -o demo-output

bench: $(STAMP)
	$(BIN)/python benchmarks/bench.py

# The held-out brain for the tissue check is the MNI152 template nilearn ships in its package data: installed
# without its dependencies (only the data files are read), skipped with a note when it cannot be installed.
evaluate: $(STAMP)
	$(BIN)/python -m pip install --quiet --disable-pip-version-check --no-deps nilearn==0.14.1 \
		|| echo "nilearn could not be installed: the held-out MNI152 tissue check will be skipped"
	$(BIN)/python benchmarks/evaluate.py

# Ours against Slicer's first click and presets. Slicer's presets.xml is read at run time, never committed:
# PRESETS=/path/presets.xml, else $$ISOSIMTF_PRESETS, ../shared/presets.xml, or a git mirror of Slicer.
compare: $(STAMP)
	$(BIN)/python benchmarks/compare.py $(if $(PRESETS),--presets "$(PRESETS)")

# Whether every use of a look threshold is tested at its boundary (about 20 min on 2 cores).
mutants: $(STAMP)
	$(BIN)/python benchmarks/rule_mutants.py

lint: $(STAMP)
	$(BIN)/ruff check .

clean:
	rm -rf $(VENV) demo-output .pytest_cache
