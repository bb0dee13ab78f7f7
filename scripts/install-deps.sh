#!/bin/sh
# Installs the system packages penumbra needs on Debian/Ubuntu (when root and something is
# missing), then checks the Rust toolchain. Safe to run repeatedly: it installs nothing when all
# is present.
#   libshaderc-dev glslang-dev spirv-tools  shaderc + glslang + SPIRV-Tools static archives:
#                                           build.rs compiles glsl/ to SPIR-V with them (no CMake)
#   libvulkan1                              the Vulkan loader (ash loads it at run time)
#   mesa-vulkan-drivers                     lavapipe, the software Vulkan device used in CI; the
#                                           newest the distribution offers: on Debian bookworm
#                                           Mesa 25 from bookworm-backports (about 2x faster than
#                                           bookworm's 22.3.6, same images), else the release's own
#   vulkan-validationlayers                 Khronos validation + synchronization validation
#                                           (--validate, and the test suite)
#   xvfb libx11-xcb1 libxcursor1 libxrandr2  an X server without a screen, and the X libraries
#   libxi6 libxkbcommon-x11-0               winit loads at run time: `penumbra view` windows in tests
#   chromium (optional)                     headless browser: the test of `render`'s graph.html
#                                           opens the page in it (skipped, said, without it);
#                                           installed when root, never required
# PENUMBRA_DISTRO_MESA=1 keeps the release's own Mesa (no backports).
set -eu
PKGS="libshaderc-dev glslang-dev spirv-tools libvulkan1 mesa-vulkan-drivers vulkan-validationlayers xvfb libx11-xcb1 libxcursor1 libxrandr2 libxi6 libxkbcommon-x11-0"
OPTIONAL="chromium"
root=0
updated=0
[ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1 && root=1
codename=""
[ -r /etc/os-release ] && codename=$(sed -n 's/^VERSION_CODENAME=//p' /etc/os-release | tr -d '"')
# installed, not merely known to dpkg (a removed package keeps "deinstall ok config-files")
installed() { dpkg-query -W -f '${Status}' "$1" 2>/dev/null | grep -q "install ok installed"; }
missing=""
for p in $PKGS; do
  installed "$p" || missing="$missing $p"
done
optional_missing=""
for p in $OPTIONAL; do
  installed "$p" || optional_missing="$optional_missing $p"
done
mesa_version() { dpkg-query -W -f '${Version}' mesa-vulkan-drivers 2>/dev/null || true; }
# Mesa's major version from a Debian version string such as 25.0.7-2~bpo12+1 or 22.3.6-1+deb12u2
mesa_major() { mesa_version | sed -n 's/^\([0-9]*:\)\{0,1\}\([0-9]*\)\..*/\2/p'; }
want_backports=0
if [ "$codename" = "bookworm" ] && [ -z "${PENUMBRA_DISTRO_MESA:-}" ]; then
  major=$(mesa_major)
  if [ -z "$major" ] || [ "$major" -lt 25 ]; then want_backports=1; fi
fi
if [ -n "$missing" ] || [ "$want_backports" = 1 ]; then
  if [ "$root" = 1 ]; then
    export DEBIAN_FRONTEND=noninteractive
    if [ "$want_backports" = 1 ]; then
      if ! grep -rqs "bookworm-backports" /etc/apt/sources.list /etc/apt/sources.list.d/; then
        echo "install-deps: adding bookworm-backports (for lavapipe from Mesa 25)" >&2
        printf '%s\n' "Types: deb" "URIs: http://deb.debian.org/debian" "Suites: bookworm-backports" \
          "Components: main" "Signed-By: /usr/share/keyrings/debian-archive-keyring.gpg" \
          > /etc/apt/sources.list.d/penumbra-bookworm-backports.sources
      fi
    fi
    apt-get update -qq
    updated=1
    if [ -n "$missing" ]; then
      echo "install-deps: installing$missing" >&2
      apt-get install -y -qq --no-install-recommends $missing >/dev/null
    fi
    if [ "$want_backports" = 1 ]; then
      echo "install-deps: installing mesa-vulkan-drivers from bookworm-backports" >&2
      apt-get install -y -qq --no-install-recommends -t bookworm-backports mesa-vulkan-drivers >/dev/null \
        || echo "install-deps: warning: bookworm-backports' Mesa could not be installed; keeping $(mesa_version)" >&2
    fi
  elif [ -n "$missing" ]; then
    echo "install-deps: missing packages:$missing (run as root, or: sudo apt-get install$missing)" >&2
    exit 1
  else
    echo "install-deps: note: lavapipe is Mesa $(mesa_version); bookworm-backports has Mesa 25, about 2x faster (as root: apt-get install -t bookworm-backports mesa-vulkan-drivers)" >&2
  fi
fi
if [ -n "$optional_missing" ]; then
  if [ "$root" = 1 ]; then
    echo "install-deps: installing (optional)$optional_missing" >&2
    { [ "$updated" = 1 ] || apt-get update -qq; } && { DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends $optional_missing >/dev/null; } \
      || echo "install-deps: warning: could not install$optional_missing (the graph.html browser check is skipped)" >&2
  else
    echo "install-deps: note: without$optional_missing the graph.html test does not open the page in a browser" >&2
  fi
fi
echo "install-deps: lavapipe from mesa-vulkan-drivers $(mesa_version)" >&2
command -v cargo >/dev/null 2>&1 || { echo "install-deps: cargo not found (install Rust with rustup)" >&2; exit 1; }
exit 0
