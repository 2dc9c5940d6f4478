# Every target creates .venv and installs the package into it, so a fresh clone needs
# nothing but Python >= 3.11 and make.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
OUT    ?= piezohyst-out

.PHONY: demo test bench bench-readme clean setup

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[test,bench,fleet,control,formats,notebooks,docs]"
	touch $(STAMP)

setup: $(STAMP)

# the documentation site in site/ (index.html), warnings as errors; and ruff (rules in
# pyproject.toml) and mypy. Each installs its extra into the same .venv.
DOCS_STAMP := $(VENV)/.installed-docs
LINT_STAMP := $(VENV)/.installed-lint
.PHONY: docs lint

$(DOCS_STAMP): pyproject.toml $(STAMP)
	$(PY) -m pip install --quiet -e ".[docs]"
	touch $(DOCS_STAMP)

$(LINT_STAMP): pyproject.toml $(STAMP)
	$(PY) -m pip install --quiet -e ".[dev]"
	touch $(LINT_STAMP)

docs: $(DOCS_STAMP)
	$(PY) -m mkdocs build --strict --site-dir site

lint: $(LINT_STAMP)
	$(PY) -m ruff check src tests
	$(PY) -m mypy src

demo: $(STAMP)
	$(VENV)/bin/piezohyst reproduce --out $(OUT) --force

# two worker processes, one test file each at a time (module fixtures are computed once)
test: $(STAMP)
	$(PY) -m pytest -q -n 2 --dist loadfile

# every row a ratio measured in the same run; writes benchmarks/out/results.json (untracked)
bench: $(STAMP)
	$(PY) benchmarks/run.py

# the README's performance table, from the last `make bench`
bench-readme:
	$(PY) benchmarks/readme_table.py

clean:
	rm -rf $(VENV) $(OUT) build site src/*.egg-info .pytest_cache
