# The two commands a newcomer runs: `make demo` and `make test`.
PYTHON ?= python3
# test processes: one per core (pytest-xdist), each test file in one process (its module
# fixtures are built once); TEST_WORKERS=0 runs the suite in one process
TEST_WORKERS ?= auto
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: demo test fuzz bench docs lint clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[dev]"
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/igljoin demo --out out/demo

test: $(STAMP)
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile

# a long hypothesis run (20,000 examples per fuzz test; make test runs 700 each)
fuzz: $(STAMP)
	HYPOTHESIS_PROFILE=fuzz $(PY) -m pytest -q tests/test_fuzz.py --hypothesis-show-statistics

docs: $(STAMP)
	$(VENV)/bin/mkdocs build --strict -d out/site

bench: $(STAMP)
	$(PY) pipelines/benchmark.py

lint: $(STAMP)
	$(VENV)/bin/ruff check igljoin pipelines tests
	$(VENV)/bin/ruff format --check igljoin pipelines tests

clean:
	rm -rf out .pytest_cache
