# Everything installs into ./.venv from scratch: `make test` on a fresh clone needs only python3.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
# The CPU wheel of torch; override on machines with another torch source, e.g. make TORCH_SPEC="torch>=2.3".
TORCH_SPEC ?= torch==2.13.0
PYTEST_ARGS ?=
# Test processes (pytest-xdist): CI has 2 cores; each test runs torch on one thread (tests/conftest.py).
TEST_WORKERS ?= 2

.PHONY: install run test test-slow test-ray lint format type bench soak notebooks clean

install: $(VENV)/.installed

$(VENV)/.installed: setup.cfg pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet "$(TORCH_SPEC)"
	$(PY) -m pip install --quiet -e ".[dev]"
	touch $@

run: install
	$(PY) examples/main_job.py

test: install
	$(VENV)/bin/lint-imports
	$(PY) -m pytest -m "not slow and not ray" -n $(TEST_WORKERS) --durations=15 -p no:cacheprovider $(PYTEST_ARGS)

# The grid's Ray backend on a local Ray instance (ray is an optional extra: about 80 MB, ~1 min of tests).
test-ray: install
	$(PY) -m pip install --quiet -e ".[dev,ray]"
	$(PY) -m pytest -m ray --durations=15 -p no:cacheprovider $(PYTEST_ARGS)

test-slow: install
	$(PY) -m pytest -m slow --durations=15 $(PYTEST_ARGS)

lint: install
	$(VENV)/bin/ruff check sb3_eps envs research tests benchmarks examples

format: install
	$(VENV)/bin/ruff format sb3_eps envs research tests benchmarks examples
	$(VENV)/bin/ruff check --fix sb3_eps envs research tests benchmarks examples

type: install
	$(VENV)/bin/mypy sb3_eps envs

bench: install
	$(PY) benchmarks/env_throughput.py

# Long-run check (about 15 minutes on 2 cores): memory, PyBullet clients and processes over 1M agent-steps of EPS-GDQ.
soak: install
	$(PY) benchmarks/soak.py --out logs/soak/soak.json

# Re-run the notebooks at their full budget, outputs written back (about 10 minutes on 2 cores); commit them.
notebooks: install
	$(PY) -m research.notebook --budget full notebooks/*.ipynb

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache build dist *.egg-info
