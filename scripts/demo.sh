#!/usr/bin/env bash
# Install datagen and run the main job on the bundled demonstration room (README: "Quick start").
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/debian_packages.sh      # libusb-1.0-0, mesa-vulkan-drivers for `datagen view` (root on Debian)
python -m pip install --quiet --disable-pip-version-check torch==2.13.0   # the CPU wheel, before the range pulls CUDA
python -m pip install --quiet --disable-pip-version-check -e .
datagen simulate scene_library/demo_room.yaml --out out/demo_room --lookins 10x10 --pixels 60x60 \
    --secondary full --orders auto "$@"
