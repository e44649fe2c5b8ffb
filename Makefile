# The two set-up commands of the README. Both create/update .venv and install everything on a fresh machine.
#   make demo   installs, then runs `lift3d demo` (the main job on a built-in synthetic scene)
#   make test   installs, then runs the test suite
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.lift3d-installed
SUDO   := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
# torch is pinned here only: this machine has the CPU build of 2.13.0 on disk, and an unpinned torch
# pulls a multi-GB CUDA build. pyproject.toml asks for any recent torch, so users with GPUs keep theirs.
TORCH_PIN ?= torch==2.13.0
PYTEST_ARGS ?=

.PHONY: install demo test clean

$(STAMP): pyproject.toml Makefile
	@# Open3D links against libusb-1.0 (Debian package libusb-1.0-0); install it only when missing.
	@$(PYTHON) -c "import ctypes.util, sys; sys.exit(0 if ctypes.util.find_library('usb-1.0') else 1)" || \
	  ($(SUDO) apt-get install -y libusb-1.0-0 || ($(SUDO) apt-get update && $(SUDO) apt-get install -y libusb-1.0-0))
	[ -x $(PY) ] || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet "$(TORCH_PIN)"
	$(PY) -m pip install --quiet -e ".[test,label,ros,octomap]"
	touch $(STAMP)

install: $(STAMP)

demo: install
	$(VENV)/bin/lift3d demo

test: install
	$(PY) -m pytest -q $(PYTEST_ARGS)

clean:
	rm -rf $(VENV) demo_out outputs .pytest_cache
