# Two commands do all set-up on a fresh machine (see README):
#   make demo   -> venv (Python 3.12) -> build a dataset, validate, plot, export; train GCSL (fast preset)
#                  until it reaches DEMO_SUCCESS of its goals, evaluate, plot and fly it to MCAP; one IPP
#                  baseline on 10 worlds (a few minutes)
#   make test   -> venv -> the whole test suite, slow end-to-end tests included
SHELL := /bin/bash
VENV  ?= .venv
BIN   := $(VENV)/bin
OUT   ?= out
GOALS ?= 250
DEMO_SUCCESS ?= 0.8
# Python 3.12 (lerobot >= 0.5 needs it): the first candidate that actually runs (a pyenv shim
# on PATH may exist but refuse), from PATH, else pyenv's versions; else fail with a clear line.
PYTHON312 ?= $(shell for p in python3.12 $$(ls -d $${PYENV_ROOT:-$$HOME/.pyenv}/versions/3.12*/bin/python3.12 2>/dev/null | sort -rV); do \
  $$p -c 'import sys; sys.exit(sys.version_info[:2] != (3, 12))' >/dev/null 2>&1 && { command -v $$p; break; }; done)
STAMP := $(VENV)/.installed

.PHONY: venv demo test test-fast lint format bench results lock clean docs

venv: $(STAMP)
$(STAMP): pyproject.toml constraints.txt
	@test -n "$(PYTHON312)" || { echo "make: error: Python 3.12 not found (install it, or set PYTHON312=/path/to/python3.12)" >&2; exit 2; }
	@test -x $(BIN)/python || $(PYTHON312) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -c constraints.txt -e ".[all,test]"
	@touch $(STAMP)

demo: venv
	$(BIN)/datagen build --goals $(GOALS) --out datasets
	@ds=$$(ls -td datasets/quadrotor-reach/n$(GOALS)-s0-* | head -n1); run=runs/demo-gcsl; \
	set -e; mkdir -p $(OUT); \
	$(BIN)/datagen validate $$ds; \
	$(BIN)/datagen info $$ds; \
	$(BIN)/datagen plot $$ds -o $(OUT)/goals.png; \
	$(BIN)/datagen export-mcap $$ds --episode 3 -o $(OUT)/ep3.mcap; \
	if [ -f $$run/config.json ]; then $(BIN)/train --resume $$run --stop-success $(DEMO_SUCCESS) --threads 1; \
	else $(BIN)/train --algo gcsl --dataset $$ds --preset fast --stop-success $(DEMO_SUCCESS) --threads 1 --name demo-gcsl; fi; \
	$(BIN)/aerohrl runs show $$run -o $(OUT)/learning_curve.png; \
	$(BIN)/aerohrl eval --task reach-desired --run $$run --checkpoints 1 --mcap-episode 3; \
	cp $$(ls $$run/eval/reach-desired/flown-episode-3-step-*.mcap | tail -n1) $(OUT)/flown-ep3.mcap; \
	$(BIN)/aerohrl eval --task reach-intermediate --run $$run --checkpoints 1; \
	$(BIN)/aerohrl eval plot --task reach-desired --run $$run -o $(OUT)/reach-desired.png; \
	$(BIN)/aerohrl ipp bench --planner greedy --envs 10 --out $(OUT)/ipp; \
	echo "demo: dataset $$ds, run $$run, figures in $(OUT)/, episode 3 flown by the policy in $(OUT)/flown-ep3.mcap (make results trains the cpu preset in full)"

# Everything CI runs: fast tests and the slow end-to-end ones.
test: venv lint
	$(BIN)/python -m pytest -m "slow or not slow" --durations=20

# ruff's lint and format checks (pyproject.toml [tool.ruff]); `make format` applies the format
lint: venv
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

format: venv
	$(BIN)/ruff format .

test-fast: venv
	$(BIN)/python -m pytest

# The whole chapter-3 reproduction (datasets -> 4 algorithms x 3 seeds + the planner experiment -> Tables 3.1/3.2 in docs/results/DATE-chapter3-tables.md); about 4 h on 2 cores, resumable.
# The training runs are Ray tasks (aerohrl sweep's machinery): RAY_ADDRESS=host:port runs them on a cluster.
RAY_ADDRESS ?=
results: venv
	$(BIN)/python experiments/reproduce.py $(if $(RAY_ADDRESS),--address $(RAY_ADDRESS))

# API reference from the docstrings (pdoc) -> docs/api/index.html
docs: venv
	$(BIN)/python docs/build_api.py docs/api

bench: venv
	@for b in bench/bench_*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

lock: venv
	{ head -n2 constraints.txt; $(BIN)/python -m pip freeze --exclude-editable | grep -v '^-e'; } > constraints.txt.new && mv constraints.txt.new constraints.txt

clean:
	rm -rf $(VENV) $(OUT) .pytest_cache
