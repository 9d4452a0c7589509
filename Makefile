# Two entry points for a fresh machine with nothing but python3: `make demo`, `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo test acceptance venv clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test]'
	touch $(STAMP)

venv: $(STAMP)

# The diagnosis at the end is of a day written by the independent bench (tests/independent_bench,
# nothing shared with the package), its truth kept beside the day where the diagnosis never reads it;
# then one of real measurements beside it: a 3C90 ferrite's measured B(t) and H(t) (mag-net-hub, MIT).
# Each run writes a folder of its own, demo-output/YYYYmmdd-HHMMSS: nothing an earlier run wrote is replaced.
demo: $(STAMP)
	@run=demo-output/$$(date +%Y%m%d-%H%M%S) && \
	(cd tests && ../$(BIN)/python -m independent_bench integrator_leak ../$$run/independent) && \
	$(BIN)/hystbench demo --out $$run --day $$run/independent/day \
	  --baseline static_hysteresis,lamination_eddy_currents,instrument_filter,sensor_noise,adc_quantisation \
	  --truth $$run/independent/truth.json && \
	$(BIN)/hystbench diagnose tests/data/real/mag-net-hub/maghub_3C90_sequence.csv --report $$run/real-waveforms

# Four workers, a test file on one worker (its module fixtures are computed once): many tests wait on a
# daemon, a socket or a subprocess, so on this 2-core machine four keep both cores busy where two left
# a third of the time idle.  Bytecode is cached even where the
# environment says PYTHONDONTWRITEBYTECODE: the suite starts some sixty Python processes (workers,
# daemons, command lines), and each compiled the package and rewrote the tests from source (a worker
# took 10 s to collect, 5 s with the cache).  --no-loadscope-reorder keeps the order tests/conftest.py
# gives the files (longest first); xdist's default reorders them by their number of tests, which sent
# the concealed suite's file (26 s alone, a fixture of one worker) out last, to run alone at the end.  One BLAS thread per process: four
# workers with two OpenBLAS threads each on two cores spent a third of the suite's CPU spinning
# (240 -> 187 s, docs/performance.md).
PYTEST := env -u PYTHONDONTWRITEBYTECODE OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 $(BIN)/python -m pytest -q -n 4 --dist loadfile --no-loadscope-reorder

# The numba kernels compiled once before the workers start (tests/warm_kernels.py: a fresh clone's
# workers each compiled them side by side, 254 s against 215 s for the next run; 2 s once cached).
test: $(STAMP)
	env -u PYTHONDONTWRITEBYTECODE $(BIN)/python tests/warm_kernels.py
	$(PYTEST)

# What make test leaves out: the whole acceptance runs (.ci/run runs this after make test).
acceptance: $(STAMP)
	$(PYTEST) -m acceptance

clean:
	rm -rf $(VENV) demo-output .pytest_cache
