# Two commands: `make demo` and `make test`. Both bootstrap .venv on first use.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: test test-fast demo lint typecheck docs docs-check venv clean

venv: $(STAMP)

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/lint-imports

# planner, mavlink and gcs ([tool.mypy] in pyproject.toml; every def typed in planner and gcs)
typecheck: $(STAMP)
	$(BIN)/mypy

# The docs as a site (mkdocs-material, README.md as its home page) into site/, offline;
# docs-check builds it strictly (a broken link or page fails) into a scratch folder.
export NO_MKDOCS_2_WARNING := 1
docs: $(STAMP)
	$(BIN)/mkdocs build --strict

docs-check: $(STAMP)
	d=$$(mktemp -d); $(BIN)/mkdocs build --strict --site-dir $$d; rc=$$?; rm -rf $$d; exit $$rc

# Three workers on two cores (some tests wait on the wall clock: transfers, timeouts);
# flights against the mock run on its simulated clock at 4x real time
# (tests/conftest.py sets STL_GCS_SIM_SPEED; docs/development.md).
test: $(STAMP) lint typecheck docs-check
	$(BIN)/python -m pytest -q -n 3 --dist load

# The fast tier: everything but the tests marked slow (flights and transfers over UDP, the
# calibration flights); for the edit-test loop, not for CI.
test-fast: $(STAMP) lint typecheck docs-check
	$(BIN)/python -m pytest -q -n 3 --dist load -m "not slow"

demo: $(STAMP)
	$(BIN)/gcs demo

clean:
	rm -rf $(VENV) build site *.egg-info
