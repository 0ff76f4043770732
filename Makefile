# Two commands for a newcomer: `make demo` and `make test`. Both create .venv
# and install the project into it (from the package registry) when missing.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp
OUT    ?= out

.PHONY: demo test test-quick programs bench bench-real lint clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	mkdir -p $(OUT)
	$(BIN)/python -m data_synth $(OUT)/demo.binary --model ggx \
		--param kd=0.12,0.08,0.05 --param ks=0.9,0.8,0.6 --param alpha=0.12 --param f0=0.7 \
		--noise 0.03 --missing 0.05
	$(BIN)/brdffit fit $(OUT)/demo.binary --model ggx --plots $(OUT)/plots
	@echo "plots: $(OUT)/plots/*.png"
	@# compiles every default model's fit into brdffit's cache (~/.cache/brdffit, or
	@# BRDFFIT_CACHE_DIR) once: a user's first fit, auto or a service then loads them
	$(BIN)/brdffit warmup

# the slowest tests are listed at the end: what to look at when the suite slows down
# pytest-xdist: one worker per core, at most 4 (each holds JAX and starts servers);
# tests that share a module's fixture stay on one worker (tests/conftest.py)
TEST_WORKERS ?= auto
XDIST := -n $(TEST_WORKERS) --maxprocesses=4 --dist loadgroup
# bytecode is written (__pycache__, which git ignores) even where the environment sets
# PYTHONDONTWRITEBYTECODE, as some images do: the suite starts ~230 Python processes (the
# CLI, servers and their workers), and each compiled brdffit's sources again without it
# (~0.25 s apiece; a fresh clone's run took 49 s less CPU with it)
PYTEST := env -u PYTHONDONTWRITEBYTECODE $(BIN)/python -m pytest
test: $(STAMP)
	$(PYTEST) -q --durations=15 $(XDIST)

# unit and contract tests (no subprocess, server or cluster), less those marked slow
# (over ~4 s each; `make test` runs every one): under 4 minutes on 2 cores
test-quick: $(STAMP)
	$(PYTEST) -q -m "not system and not slow" --durations=15 $(XDIST)

# the default fits' programs lowered (StableHLO, jax.export) and shipped in the package:
# a new process compiles them without tracing. Run after changing what they import
# (brdffit/models, brdffit/fitting, brdffit/selection.py, ...); tests/test_exported.py fails while they are stale
programs: $(STAMP)
	$(BIN)/python -m brdffit.build_programs build

bench: $(STAMP)
	$(BIN)/python -m bench

# every model on the 100 real MERL materials against a best-effort reference
# (tables and references cached in .bench-cache/; the first run takes ~1.5 h on 2 cores)
bench-real: $(STAMP)
	$(BIN)/python -m bench.real_materials

lint: $(STAMP)
	$(BIN)/ruff check brdffit api data_synth tests bench

clean:
	rm -rf $(OUT) .pytest_cache
