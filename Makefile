# armvision: `make demo` and `make test` are all a new user needs; both set themselves up.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
# Debian packages: libusb for pyrealsense2, EGL/GL and Mesa's software renderer for offscreen
# MuJoCo, and chromium (with a font) for the UI's end-to-end tests, headless under Playwright.
APT_PACKAGES := libusb-1.0-0 libegl1 libgl1 libegl-mesa0 libgl1-mesa-dri chromium fonts-dejavu-core
STAMP  := $(VENV)/.armvision-installed
# Extras `make setup` installs; realsense is dropped (with a message) where pyrealsense2 has no wheel.
EXTRAS := dev,realsense

export MUJOCO_GL ?= egl

.PHONY: setup system-packages demo test bench lint check-wheels check-aarch64 clean

setup: system-packages $(STAMP)

system-packages:
	@sh scripts/system-packages.sh $(APT_PACKAGES)

# Reinstalled only when pyproject.toml changes, so a second `make setup` is instant.
# resolve_platform.py --here asks pip what it would install here: where a package has no wheel
# and must be compiled (pupil-apriltags on aarch64) it installs the build packages first, and it
# leaves out an optional extra with no wheel (pyrealsense2 on aarch64 Python 3.11), saying why.
$(STAMP): pyproject.toml
	@sh scripts/check-python.sh $(PYTHON)
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	@extras=$$($(BIN)/python scripts/resolve_platform.py --here --extras $(EXTRAS) --optional realsense) && \
	  echo "$(BIN)/python -m pip install --quiet -e '.[$$extras]'" && \
	  $(BIN)/python -m pip install --quiet -e ".[$$extras]"
	@echo "compiling the perception kernels (Numba; cached, once)"
	@$(BIN)/python -c "from armvision.perception.geometric import compile_kernels; compile_kernels()"
	@touch $(STAMP)

# The whole system on a simulated scene: calibrate, detect, analyse, grab; a report against the truth.
demo: setup
	$(BIN)/armvision demo --seed 0 --out out/demo

test: setup
	$(BIN)/python -m pytest

bench: setup
	$(BIN)/python benchmarks/run_all.py

# Style (ruff), the import layers (import-linter, contracts in pyproject.toml) and types (mypy).
lint: setup
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/ruff format --check src tests benchmarks
	$(BIN)/lint-imports
	$(BIN)/mypy

# Not part of `make test` (both talk to PyPI). The aarch64 wheel table for Python 3.10-3.13:
check-wheels: setup
	$(BIN)/python scripts/resolve_platform.py

# arm64 Debian under qemu-user-static: make setup, info, perceive on a saved frame, fast tests.
AARCH64_FRAME := build/aarch64-frame
check-aarch64: setup
	$(BIN)/armvision sim snapshot --seed 3 --pose sleep --out $(AARCH64_FRAME)
	sh scripts/check-aarch64.sh $(AARCH64_FRAME)

clean:
	rm -rf $(VENV) build src/*.egg-info .pytest_cache .ruff_cache
