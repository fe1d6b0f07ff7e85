# baarda — two commands set everything up on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   ?= .venv
PY      = $(VENV)/bin/python
BAARDA  = $(VENV)/bin/baarda
STAMP   = $(VENV)/.installed
RUN    ?= runs/demo
# Tests and benchmarks run single-threaded BLAS: on a shared 2-core machine threaded OpenBLAS
# makes the small dense solves of the bundle much slower, and timings become irreproducible.
TESTENV = OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1

.PHONY: demo test test-slow bench venv clean

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $(STAMP)

venv: $(STAMP)

demo: $(STAMP)
	$(BAARDA) run fixtures/paper000/data1.toml --out $(RUN)
	@echo
	@echo "Run directory: $(RUN)   (inspect with: $(BAARDA) review $(RUN))"

# pytest-xdist: one worker per core (TEST_WORKERS=0 runs in one process); each test file stays on
# one worker (--dist loadfile), so a module's fixtures (whole project runs) are computed once.
TEST_WORKERS ?= auto
XDIST = -n $(TEST_WORKERS) --dist loadfile

test: $(STAMP)
	$(TESTENV) $(PY) -m pytest -q $(XDIST)

test-slow: $(STAMP)
	$(TESTENV) $(PY) -m pytest -q -m slow $(XDIST)

bench: $(STAMP)
	$(TESTENV) $(PY) -m pytest -q -s -m benchmark

# The adjustment at scale (docs/benchmarks.md, "Scale"): aerial blocks of 500 … 10 000 photos and
# BAL problem-49, baarda beside pycolmap, each solver in its own process; up to an hour or more.
SCALE_ARGS ?= --sizes 500 1000 2000 5000 10000 --bal
# Monte Carlo of the congruence test on the test field's precision (--network panel: the panel) (docs/monitoring.md)
.PHONY: bench-congruence
bench-congruence: $(STAMP)
	$(TESTENV) $(PY) benchmarks/congruence_mc.py --n 3000

.PHONY: bench-scale
bench-scale: $(STAMP)
	$(TESTENV) $(PY) benchmarks/scale.py $(SCALE_ARGS)

# Full-page screenshots of every bundled project's report.html (headless Chromium, Debian's package,
# installed with apt when missing) into docs/images/ (900 px wide PNG); prints each page's height in
# 1080-px screens before its appendix of tables.  Runs every bundled project first (a few minutes).
.PHONY: screenshots
screenshots: $(STAMP)
	command -v chromium >/dev/null || command -v chromium-browser >/dev/null || \
	  { if [ "$$(id -u)" = 0 ]; then apt-get install -y chromium; else sudo apt-get install -y chromium; fi; }
	$(TESTENV) $(PY) tools/screenshots.py --run --out runs/screenshots --images docs/images

clean:
	rm -rf $(VENV) runs .pytest_cache

# Whole runs against pycolmap (docs/benchmarks.md, "Whole runs"): `baarda run` of simulated aerial
# blocks written as BAL projects (every output written) against pycolmap's SPARSE_SCHUR and default
# solves, and DBAT's 60-photo Roma project (from a DBAT repository, see the script); not part of
# `make test`.  The 10 000-photo block takes ≈ 15–25 minutes with pycolmap's two solves:
# RUN_ARGS="--sizes 2000 --floor" for the short set.
RUN_ARGS ?= --sizes 2000 10000 --floor
.PHONY: bench-run
bench-run: $(STAMP)
	$(TESTENV) $(PY) benchmarks/run_vs_pycolmap.py $(RUN_ARGS)
