# armvision: `make demo` and `make test` are all a new user needs; both set themselves up.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
# Debian packages: libusb for pyrealsense2, EGL/GL and Mesa's software renderer for offscreen
# MuJoCo, and chromium (with a font) for the UI's end-to-end tests, headless under Playwright.
APT_PACKAGES := libusb-1.0-0 libegl1 libgl1 libegl-mesa0 libgl1-mesa-dri chromium fonts-dejavu-core
STAMP  := $(VENV)/.armvision-installed

export MUJOCO_GL ?= egl

.PHONY: setup system-packages demo test bench lint clean

setup: system-packages $(STAMP)

system-packages:
	@sh scripts/system-packages.sh $(APT_PACKAGES)

# Reinstalled only when pyproject.toml changes, so a second `make setup` is instant.
$(STAMP): pyproject.toml
	@sh scripts/check-python.sh $(PYTHON)
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
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

clean:
	rm -rf $(VENV) build src/*.egg-info .pytest_cache .ruff_cache
