# Everything a newcomer needs on a fresh machine with Python >= 3.10 and pip: `make test`, `make demo`.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: install test demo bench clean

install: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	@touch $(STAMP)

test: $(STAMP)
	$(BIN)/python -m pytest -q

demo: $(STAMP)
	$(BIN)/replanner demo

bench: $(STAMP)
	$(BIN)/replanner bench collision

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache
