# Two entry points (see README): `make demo` and `make test`.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
OUT    ?= demo-output

.PHONY: setup demo test lint bench clean

$(BIN)/stableins: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(BIN)/stableins

setup: $(BIN)/stableins

demo: setup
	$(BIN)/stableins demo --out $(OUT)

test: setup
	$(BIN)/ruff check stableins tests $(wildcard benchmarks/*.py)
	MPLBACKEND=Agg $(BIN)/python -m pytest

lint: setup
	$(BIN)/ruff check stableins tests $(wildcard benchmarks/*.py)

bench: setup
	for f in benchmarks/bench_*.py; do $(BIN)/python $$f || exit 1; done

clean:
	rm -rf $(VENV) $(OUT) .pytest_cache
