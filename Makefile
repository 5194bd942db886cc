# Two commands on a fresh machine with only Python ≥ 3.11 and pip:
#   make demo   set up .venv, install, reproduce Table 2 on the virtual IPMC
#   make test   set up .venv, install, run the tests
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test docs bench bench-quick install clean rig-deps bench-peers bench-peers-quick

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test,docs]'
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/python experiments/table2.py

test: $(STAMP) rig-deps
	$(BIN)/python -m pytest -q -n 2 --dist loadfile --durations=25

# the documentation (docs/, mkdocs.yml) into site/; a broken link or reference fails it
docs: $(STAMP)
	$(BIN)/mkdocs build --strict

# full benchmarks (~15 min on 2 cores) and the quick ratios (< 45 s); both write benchmarks/results/*.json
BENCH_STAMP := $(VENV)/.installed-bench

$(BENCH_STAMP): pyproject.toml | $(STAMP)
	$(BIN)/python -m pip install --quiet -e '.[test,bench]'
	touch $(BENCH_STAMP)

bench: $(BENCH_STAMP)
	$(BIN)/python benchmarks/quick.py
	$(BIN)/python benchmarks/simulate.py
	$(BIN)/python benchmarks/jacobian.py
	$(BIN)/python benchmarks/lm_step.py
	$(BIN)/python benchmarks/fitting.py
	$(BIN)/python benchmarks/batch_fit.py
	$(BIN)/python benchmarks/memory.py
	$(BIN)/python benchmarks/diagnose.py
	$(BIN)/python benchmarks/compile_emitters.py
	$(BIN)/python benchmarks/startup.py

bench-quick: $(STAMP)
	$(BIN)/python benchmarks/quick.py

# The tools a lab would pick instead (SysIdentPy, pysindy, jax-sysid), each in its own environment built
# once from pinned requirements (jax-sysid pins an older JAX than ours); the project's .venv stays as it is.
# bench-peers: the full side-by-side (< 30 min on 2 cores) writes benchmarks/results/peers.{md,json} and
# experiments/results/table2_baselines.md; bench-peers-quick: every peer on a short slice (< 2 min).
PEERS_STAMP := .venv-peers/.installed
JAXSYSID_STAMP := .venv-jaxsysid/.installed

$(PEERS_STAMP): benchmarks/peers/requirements.txt
	$(PYTHON) -m venv .venv-peers
	.venv-peers/bin/python -m pip install --quiet -r benchmarks/peers/requirements.txt
	touch $(PEERS_STAMP)

$(JAXSYSID_STAMP): benchmarks/peers/requirements-jaxsysid.txt
	$(PYTHON) -m venv .venv-jaxsysid
	.venv-jaxsysid/bin/python -m pip install --quiet -r benchmarks/peers/requirements-jaxsysid.txt
	touch $(JAXSYSID_STAMP)

bench-peers: $(STAMP) $(PEERS_STAMP) $(JAXSYSID_STAMP)
	$(BIN)/python benchmarks/peers/run.py

bench-peers-quick: $(STAMP) $(PEERS_STAMP) $(JAXSYSID_STAMP)
	$(BIN)/python benchmarks/peers/run.py --quick --out benchmarks/results/peers_quick.json --table2-out benchmarks/results/table2_baselines_quick.md

clean:
	rm -rf $(VENV) *.egg-info .pytest_cache

# The rig's firmware tests build the sketch with avr-gcc and run it on simavr.
# Installed with apt where we are root on Debian (as in CI); elsewhere those
# tests skip with the reason, and this target never fails the build.
RIG_DEBS := gcc-avr avr-libc simavr libsimavr-dev gcc pkg-config libelf-dev
rig-deps:
	@if command -v avr-g++ >/dev/null 2>&1 && [ -f /usr/include/simavr/sim_avr.h ]; then :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
		(apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $(RIG_DEBS)) >/dev/null 2>&1 \
		|| echo "rig-deps: apt-get could not install $(RIG_DEBS); the simavr tests will skip"; \
	else echo "rig-deps: not root or no apt-get; install $(RIG_DEBS) to run the simavr tests"; fi
