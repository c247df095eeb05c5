# Two commands set everything up on a fresh Debian 12 machine:
#   make render   - installs PoCL and rtlab (in .venv), renders the default scene to render.png
#   make test     - the same set-up plus the dev tools, then the whole test suite on PoCL
PY ?= python3
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: setup render test bench-build
setup: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml scripts/install_system_deps.sh
	bash scripts/install_system_deps.sh
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e '.[dev,viz]'
	touch $@

render: setup
	$(BIN)/rtlab render --out render.png

test: setup
	$(BIN)/python -m pytest -q --timeout=900

bench-build: setup
	$(BIN)/python benchmarks/bench_kdtree_build.py
