# The two commands of the README: `make demo` and `make test`. Both create .venv on first use.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
INSTALLED := $(VENV)/.installed
SOURCES := $(shell find moseg_ros config launch resource -type f -not -name '*.pyc') setup.py setup.cfg package.xml
export OPENBLAS_NUM_THREADS := 1

.PHONY: demo test install clean

install: $(INSTALLED)

$(VENV)/.requirements: requirements.txt
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --disable-pip-version-check -r requirements.txt
	touch $@

# `pip install .`, not -e: editable installs skip data_files (the ament index marker, share/).
$(INSTALLED): $(VENV)/.requirements $(SOURCES)
	$(BIN)/pip install --quiet --disable-pip-version-check --no-deps --force-reinstall .
	touch $@

demo: $(INSTALLED)
	$(BIN)/moseg demo --out out

test: $(INSTALLED)
	$(BIN)/ruff check .
	$(BIN)/python -m pytest test

clean:
	rm -rf out build install log *.egg-info
