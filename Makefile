# Everything a newcomer needs on a fresh machine with Python >= 3.10 and pip: `make test`, `make demo`.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: install browser test demo bench clean

install: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	@touch $(STAMP)

# The web view's test drives Debian's chromium headless through chromedriver (apt-get, as root or with sudo);
# nothing downloads a browser at run time.
browser:
	@command -v chromium >/dev/null && command -v chromedriver >/dev/null || { \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get update -qq && $$SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium chromium-driver; }

# two workers, a test file each at a time: most of the suite waits on processes, motions and a browser
test: $(STAMP) browser
	$(BIN)/python -m pytest -q -n 2 --dist loadfile

demo: $(STAMP)
	$(BIN)/replanner demo --view

bench: $(STAMP)
	$(BIN)/replanner bench collision

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache
