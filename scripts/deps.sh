# Sourced by the scripts and .ci/run: installs the Debian packages the project needs, once.
# shellcheck shell=bash
#   Vulkan on the CPU (Mesa lavapipe) for the wgpu paths, which fail loudly without an adapter;
#   Slurm and munge for the farm
#   test (pinbake/tests/it/slurm.rs starts a single-node cluster with scripts/slurm-local.sh);
#   OpenVDB's C++ library, Boost headers and g++ for the VDB compatibility corpus
#   (pinbake/tests/it/vdb_corpus.rs writes its files with OpenVDB itself); nanovdb_convert
#   (libnanovdb-tools) for the NanoVDB corpus (pinbake/tests/it/nanovdb_corpus.rs); spirv-val and
#   glslangValidator for the generated shaders (lab/tests/it/shaders.rs); valgrind for the C
#   example (capi/tests/it/c_example.rs); python3-venv for the Python package's tests; xvfb and
#   libxkbcommon-x11-0 for the viewer's window tests (pinview/tests/it/ start Xvfb themselves).
APT_PACKAGES="mesa-vulkan-drivers libvulkan1 slurm-wlm munge g++ libopenvdb-dev libboost-dev libnanovdb-tools spirv-tools glslang-tools valgrind python3-venv xvfb libxkbcommon-x11-0"
export DEBIAN_FRONTEND=noninteractive
SUDO=""
if [ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null; then SUDO=sudo; fi
# shellcheck disable=SC2086
if ! dpkg -s $APT_PACKAGES >/dev/null 2>&1; then
  echo "installing Debian packages: $APT_PACKAGES" >&2
  $SUDO apt-get update -qq
  # shellcheck disable=SC2086
  # Without the packages' recommendations (valgrind's debug symbols and gdb, xvfb's xauth):
  # nothing here uses them, and they were half of the install's time (21 s against 12 s).
  $SUDO apt-get install -y -qq --no-install-recommends $APT_PACKAGES >/dev/null
fi
