# Set-up commands for a fresh machine: `make .venv` (only the environment), `make demo` and
# `make test`. Each creates .venv and installs torchcal (with its dev extra) when missing;
# then `. .venv/bin/activate` puts `torchcal` and the venv's `python` (numpy, torch, ...)
# on the PATH, or call `.venv/bin/torchcal` and `.venv/bin/python` directly.
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: .venv demo test bench clean

$(STAMP): pyproject.toml
	python3 -m venv $(VENV)
	# a local CPU build of torch (pip's find-links), when the machine has one, goes in first;
	# its dependencies come with the next line, and the torch range there keeps it
	-$(PY) -m pip install -q --no-index --no-deps torch==2.13.0 2>/dev/null
	$(PY) -m pip install -q -e '.[dev]'
	touch $(STAMP)

# `make .venv`: the environment alone (phony: it re-installs when pyproject.toml changed)
.venv: $(STAMP)
	@echo "torchcal is installed in .venv: run '. .venv/bin/activate' (or call .venv/bin/torchcal)"

demo: $(STAMP)
	$(VENV)/bin/torchcal demo

test: $(STAMP)
	# one worker per core (pytest-xdist, --dist worksteal); each runs torch on one thread (tests/conftest.py)
	$(PY) -m pytest -q -n auto

bench: $(STAMP)
	for b in benchmarks/bench_*.py; do $(PY) $$b || exit 1; done

clean:
	rm -rf $(VENV) build *.egg-info
