#!/bin/sh
# Stands in for cmake during the build (.cargo/config.toml sets CMAKE to this script): the
# shaderc-sys crate falls back to a 6-minute CMake build of shaderc from source when it does not
# find shaderc's static archive; penumbra links Debian's static archives instead. Fail at once,
# saying what to install.
echo "penumbra: shaderc's static library (libshaderc_combined.a) was not found, and penumbra does not build shaderc from source with CMake." >&2
echo "penumbra: install Debian's libshaderc-dev glslang-dev spirv-tools (sh scripts/install-deps.sh does, as root), or set SHADERC_LIB_DIR to the folder holding libshaderc_combined.a and libglslang.a." >&2
echo "penumbra: to build shaderc from source anyway, set CMAKE=cmake." >&2
exit 1
