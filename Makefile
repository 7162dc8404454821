# Two entry points (see README): `make demo` and `make test`.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
OUT    ?= demo-output

.PHONY: setup system-deps demo test installed-demo lint format docs bench clean

$(BIN)/stableins: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(BIN)/stableins

setup: $(BIN)/stableins

demo: setup
	$(BIN)/stableins demo --out $(OUT)

# Debian's packages the suite uses, installed with apt when root (CI runs as root): poppler-utils (pdftoppm,
# pdftotext) lets the report test render the PDF; chromium and chromium-driver let the browser tests of
# `stableins serve` drive headless Chromium (tests/test_serve_browser.py); postgresql gives the server the
# PostgreSQL history-store tests start (tests/test_history_postgres.py).  Without root, the tests that need a
# missing one are skipped with the reason.
# (program:package; PostgreSQL's initdb is not on PATH on Debian, and psql alone is only the client)
SYSTEM_DEPS := pdftoppm:poppler-utils chromium:chromium chromedriver:chromium-driver
system-deps:
	@missing=""; for pair in $(SYSTEM_DEPS); do \
	  command -v "$${pair%%:*}" >/dev/null 2>&1 || missing="$$missing $${pair#*:}"; done; \
	ls /usr/lib/postgresql/*/bin/initdb >/dev/null 2>&1 || command -v initdb >/dev/null 2>&1 || missing="$$missing postgresql"; \
	if [ -n "$$missing" ]; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    apt-get update -qq >/dev/null && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing >/dev/null; \
	  else echo "note: not installed (no root/apt):$$missing; the tests that need them will be skipped" >&2; fi; fi

test: setup system-deps lint
	MPLBACKEND=Agg $(BIN)/python -m pytest -n auto
	$(MAKE) --no-print-directory docs
	$(MAKE) --no-print-directory installed-demo

# The wheel as a user installs it: built from this checkout, installed into a fresh venv outside it,
# `stableins demo` run there (version and procedures must come from the package, not the checkout).
installed-demo: setup
	MPLBACKEND=Agg PYTHON=$(PYTHON) .ci/installed-demo

# ruff (lint and format) and mypy, and the allow-lists of not-yet-clean files in pyproject.toml exact (they only shrink).
lint: setup
	$(BIN)/ruff check stableins tests tools $(wildcard benchmarks/*.py)
	$(BIN)/ruff format --check stableins tests tools benchmarks
	$(BIN)/mypy
	$(BIN)/python tools/lint_allowlists.py --check

# Format the tree as make lint requires (ruff format; the line length is pyproject.toml's).
format: setup
	$(BIN)/ruff format stableins tests tools benchmarks

# The API reference from the numpydoc docstrings (docs/api/_build/html/index.html): a fresh build (-E, so
# every warning is seen again) with warnings as errors; no network.
docs: setup
	MPLBACKEND=Agg $(BIN)/sphinx-build -b html -E -q -W --keep-going -j auto docs/api docs/api/_build/html

bench: setup
	for f in benchmarks/bench_*.py; do $(BIN)/python $$f || exit 1; done

clean:
	rm -rf $(VENV) $(OUT) .pytest_cache .mypy_cache docs/api/_build docs/api/modules
