#!/usr/bin/env bash
# Prepares, on this machine (Blender, pip and apt reach their registries here), everything
# benchmarks/gpu_peer.sh needs on a lent GPU machine that reaches nothing, and prints the one
# device command that runs it:
#   .gl/        the GL and Vulkan loaders as Debian packages (unpacked there with dpkg -x)
#   .whl/       moderngl and glcontext for that machine's Python 3.12 (its numpy is there)
#   out/gpu/    the scenes pickled (forest, clusters, city, 1M triangles, soft_lights) and the
#               peer tree (`git archive PEER`)
# The three folders are git-ignored; the device call carries them (well under its 64 MiB).
#
#   bash benchmarks/gpu_prepare.sh PEER_COMMIT
set -euo pipefail
peer=${1:?usage: bash benchmarks/gpu_prepare.sh PEER_COMMIT}
cd "$(dirname "$0")/.."
rev=$(git rev-parse --verify "$peer^{commit}")
rm -rf .gl .whl out/gpu
mkdir -p .gl .whl out/gpu/peer /tmp/hs-amd64/partial
o="-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/hs-amd64"
# shellcheck disable=SC2086
apt-get $o update -qq >/dev/null
# shellcheck disable=SC2086
(cd .gl && apt-get $o download -qq libvulkan1 libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2 >/dev/null)
plat=()
for n in 28 27 17; do plat+=(--platform "manylinux_2_${n}_x86_64"); done
python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    "${plat[@]}" --platform manylinux2014_x86_64 -d .whl \
    "$(grep -E '^moderngl==' requirements.txt | cut -d' ' -f1)" "$(grep -E '^glcontext==' requirements.txt | cut -d' ' -f1)"
.venv/bin/python -m tools.pickle_scenes --output-dir out/gpu/scenes forest clusters city \
    "scaling:triangles=1000000" soft_lights >/dev/null
git archive "$rev" | tar -x -C out/gpu/peer
echo "prepared: $(du -sh .gl .whl out/gpu | awk '{printf "%s %s  ", $2, $1}')(peer ${rev:0:7})"
cat <<'EOF'
device call (carry: .gl .whl out/gpu; timeout_s 540):
  for f in .gl/*.deb; do dpkg -x $f /; done; ldconfig;
  export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
  export PYTHONPATH=/tmp/site PYTHONUNBUFFERED=1
  bash benchmarks/gpu_peer.sh out/gpu/peer out/gpu/scenes $OUT/gpu 2>&1 | tee $OUT/gpu.log
EOF
