#!/usr/bin/env bash
# Install datagen with its test extras and run the test suite (README: "Run the tests").
set -euo pipefail
cd "$(dirname "$0")/.."
python -m pip install --quiet --disable-pip-version-check -e ".[test]"
python -m pytest -q
