# One entry point for people and CI. `make demo` and `make test` install everything first.
PYTHON ?= python3
PIP := $(PYTHON) -m pip --disable-pip-version-check
# Every plugin distribution under plugins/ is installed editable, in sorted order.
PLUGINS := $(sort $(dir $(wildcard plugins/*/pyproject.toml)))

.PHONY: install demo test lint bench

install:
	# torch first, pinned: 2.13.0 is the CPU build; an unpinned torch would pull several GB of CUDA packages.
	$(PIP) install torch==2.13.0
	$(PIP) install -e ".[test]" $(addprefix -e ,$(PLUGINS))

demo: install
	$(PYTHON) -m vladrivebench._cli.main demo

test: install
	$(PYTHON) -m ruff check .
	$(PYTHON) -m pytest -q

lint:
	$(PYTHON) -m ruff check .

BENCHMARKS := $(sort $(wildcard benchmarks/*.py plugins/*/benchmarks/*.py))

bench:
	@for script in $(BENCHMARKS); do echo "== $$script"; $(PYTHON) $$script || exit 1; done
