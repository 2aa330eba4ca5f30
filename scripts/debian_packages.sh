#!/usr/bin/env bash
# Debian packages that open3d's offscreen renderer (`datagen view`) needs: libusb-1.0-0 (loaded by
# `import open3d`) and mesa-vulkan-drivers (a software Vulkan driver, llvmpipe). Run by scripts/test.sh and
# scripts/demo.sh. As root on Debian it installs the missing ones (one `apt-get update`, then a quiet
# `apt-get install -y`); packages already installed are skipped. Otherwise it prints the command to run and
# goes on: everything but `datagen view` works without them.
set -uo pipefail
packages=(libusb-1.0-0 mesa-vulkan-drivers)
command -v dpkg-query >/dev/null 2>&1 || {
    echo "note: not Debian; for datagen view install libusb-1.0 and a Vulkan driver (Mesa's lavapipe/llvmpipe)" >&2
    exit 0
}
missing=()
for p in "${packages[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
((${#missing[@]})) || exit 0
if [[ $(id -u) -eq 0 ]] && command -v apt-get >/dev/null 2>&1; then
    export DEBIAN_FRONTEND=noninteractive
    if apt-get update -qq >/dev/null && apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null; then
        exit 0
    fi
    echo "note: apt-get could not install ${missing[*]}; datagen view will not render without them" >&2
else
    echo "note: datagen view needs the Debian packages ${missing[*]}: sudo apt-get install -y ${missing[*]}" >&2
fi
exit 0
