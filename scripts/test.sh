#!/usr/bin/env bash
# Install datagen with its test and docs extras, check the layer contract, run the test suite and build the docs
# site strictly (README: "Tests").
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/debian_packages.sh      # libusb-1.0-0, mesa-vulkan-drivers for `datagen view` (root on Debian)
python -m pip install --quiet --disable-pip-version-check torch==2.13.0   # the CPU wheel, before the range pulls CUDA
python -m pip install --quiet --disable-pip-version-check -e ".[test,docs]"
lint-imports --no-cache          # layers of docs/architecture.md (pyproject.toml [tool.importlinter]); fails CI
python -m pytest -q -n auto --dist loadfile   # one process per core; a file's tests stay together (module fixtures)
NO_MKDOCS_2_WARNING=1 mkdocs build --strict --quiet --site-dir "${TMPDIR:-/tmp}/datagen-site"   # broken links, missing references fail
