#!/usr/bin/env bash
# Installs what building and testing volwarp needs on a fresh Debian machine (run as root, or
# with sudo available). Idempotent: skips what is already there.
set -euo pipefail
cd "$(dirname "$0")/.."

SUDO=""
if [ "$(id -u)" != 0 ] && command -v sudo >/dev/null; then SUDO=sudo; fi

# System packages: lavapipe (software Vulkan) for the GPU tests, Xvfb for the window test.
need=()
# gcc-aarch64-linux-gnu: minifb's, zstd-sys's and ring's build scripts compile C for the ARM
# build of the client, and it links the aarch64 test binaries; libc6-dev-arm64-cross: the C
# library headers and the aarch64 libc they run against (only a "Recommends" of the compiler,
# which --no-install-recommends leaves out); qemu-user: runs those aarch64 binaries here.
# mpich, libmpich-dev: the MPI the server's feature `mpi` links (rsmpi) and whose mpiexec the
# end-to-end tests launch; libclang-dev: bindgen, which rsmpi's build runs over mpi.h.
for p in mesa-vulkan-drivers libvulkan1 xvfb xauth x11-apps xdotool gcc-aarch64-linux-gnu libc6-dev-arm64-cross qemu-user \
  mpich libmpich-dev libclang-dev; do
  dpkg -s "$p" >/dev/null 2>&1 || need+=("$p")
done
if [ ${#need[@]} -gt 0 ]; then
  echo "setup: installing ${need[*]}"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null
fi

# The no_std target core is checked for.
rustup target list --installed | grep -q thumbv7em-none-eabihf || rustup target add thumbv7em-none-eabihf
# The ARM (aarch64 Linux) thin-client target the client and its renderers are checked for.
rustup target list --installed | grep -q aarch64-unknown-linux-gnu || rustup target add aarch64-unknown-linux-gnu

# Fuzz smoke runs need cargo-fuzz and a nightly toolchain.
if [ "${VOLWARP_NO_FUZZ:-0}" != 1 ]; then
  rustup toolchain list | grep -q nightly || rustup toolchain install nightly --profile minimal
  command -v cargo-fuzz >/dev/null || cargo install cargo-fuzz --locked
fi
