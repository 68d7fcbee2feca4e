PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test lint bench clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[dev]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/prismstereo warmup --methods bpasw --parts depth    # the kernels the demo runs, not every matcher's
	$(BIN)/prismstereo demo -o demo_out

# two pytest processes (pytest-xdist), each taking whole test files so that a file's module fixtures are built
# once: CI and the developers' machines have 2 cores, and most of the suite runs on one. Both processes share
# .numba_cache (numba writes each cache file under a temporary name and renames it).
TEST_WORKERS ?= 2

# The warm-up first compiles every kernel into that cache in TEST_WORKERS processes, one item each, so that a
# fresh clone does not compile a kernel twice (two pytest processes reaching it before either has written the
# cache) nor pay it at the tail of one worker; on a warm cache it only loads them (seconds).
test: $(STAMP)
	NUMBA_CACHE_DIR=$(CURDIR)/.numba_cache $(BIN)/prismstereo warmup --jobs $(TEST_WORKERS) -q
	NUMBA_CACHE_DIR=$(CURDIR)/.numba_cache $(BIN)/python -m pytest -n $(TEST_WORKERS) --dist loadfile

lint: $(STAMP)
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/mypy

bench: $(STAMP)
	$(BIN)/python benchmarks/bench_matching.py

clean:
	rm -rf $(VENV) demo_out .numba_cache .pytest_cache
