#!/bin/sh
# Installs the system packages penumbra needs on Debian/Ubuntu (when root and something is
# missing), then checks the Rust toolchain. Safe to run repeatedly: it installs nothing when all
# is present.
#   libshaderc-dev glslang-dev spirv-tools  shaderc + glslang + SPIRV-Tools static archives:
#                                           build.rs compiles glsl/ to SPIR-V with them (no CMake)
#   libvulkan1                              the Vulkan loader (ash loads it at run time)
#   mesa-vulkan-drivers                     lavapipe, the software Vulkan device used in CI
#   vulkan-validationlayers                 Khronos validation + synchronization validation
#                                           (--validate, and the test suite)
#   xvfb libx11-xcb1 libxcursor1 libxrandr2  an X server without a screen, and the X libraries
#   libxi6 libxkbcommon-x11-0               winit loads at run time: `penumbra view` windows in tests
set -eu
PKGS="libshaderc-dev glslang-dev spirv-tools libvulkan1 mesa-vulkan-drivers vulkan-validationlayers xvfb libx11-xcb1 libxcursor1 libxrandr2 libxi6 libxkbcommon-x11-0"
missing=""
for p in $PKGS; do
  dpkg -s "$p" >/dev/null 2>&1 || missing="$missing $p"
done
if [ -n "$missing" ]; then
  if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
    echo "install-deps: installing$missing" >&2
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq
    apt-get install -y -qq --no-install-recommends $missing >/dev/null
  else
    echo "install-deps: missing packages:$missing (run as root, or: sudo apt-get install$missing)" >&2
    exit 1
  fi
fi
command -v cargo >/dev/null 2>&1 || { echo "install-deps: cargo not found (install Rust with rustup)" >&2; exit 1; }
exit 0
