# Two commands set everything up on a fresh Debian 12 machine:
#   make render   - installs PoCL and rtlab (in .venv), renders the default scene to render.png
#   make test     - the same set-up plus the dev tools, then the whole test suite on PoCL
# (rtlab also installs without this Makefile: `pip install .` or a wheel works from any directory,
# kernels and lab steps ship inside the package; scripts/check_wheel.sh checks that.)
PY ?= python3
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: setup setup-dev render test bench-build check-wheel
setup: $(VENV)/.installed
setup-dev: $(VENV)/.installed-dev

$(VENV)/.installed: pyproject.toml scripts/install_system_deps.sh
	bash scripts/install_system_deps.sh
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e .
	touch $@

# pytest, jupytext, pyvista (large), embreex (bench cpu): only what the tests need, not what render needs
$(VENV)/.installed-dev: $(VENV)/.installed
	$(BIN)/pip install -q -e '.[dev,viz,bench]'
	touch $@

# Whitted ray tracing of the procedural default scene: shadows, a mirror and a glass sphere
render: setup
	$(BIN)/rtlab render --shadows one-pass --bounces 2 --out render.png

# both cores: one test process a core (the grading tests start their own test processes besides)
test: setup-dev
	$(BIN)/python -m pytest -q -n 2 --timeout=900

bench-build: setup
	$(BIN)/python experiments/bench_kdtree_build.py

check-wheel: setup
	bash scripts/check_wheel.sh
