#!/usr/bin/env bash
# Install datagen with its test extras, check the layer contract and run the test suite (README: "Run the tests").
set -euo pipefail
cd "$(dirname "$0")/.."
python -m pip install --quiet --disable-pip-version-check -e ".[test]"
lint-imports --no-cache          # layers of docs/architecture.md (pyproject.toml [tool.importlinter]); fails CI
python -m pytest -q
