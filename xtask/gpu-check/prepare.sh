#!/usr/bin/env bash
# Lays out everything the GPU device check needs in one ignored folder, .gpu-check/ at the
# repository root: a stripped release `octoproxy` (with the bench), the Vulkan loader's .deb
# and libglvnd's (a bare device machine has neither; NVIDIA's Vulkan driver needs both), and
# the shared meshes the bench reads. Run it here, where
# the Rust toolchain is; then run the device command in the README, which carries the folder.
#
#   bash xtask/gpu-check/prepare.sh            # build and lay out .gpu-check/
#   bash xtask/gpu-check/prepare.sh --check    # and run the check here on any adapter
#                                              # (lavapipe), small, from the same folder
set -euo pipefail
root="$(cd "$(dirname "$0")/../.." && pwd)"
cd "$root"
dir=.gpu-check
meshes_src="${OCTOPROXY_MESHES:-$root/../shared/meshes}"
# The bench scenes: the bunny, Nefertiti (also subdivided to 6.4M triangles), the ogre, the beast.
meshes=(stanford-bunny nefertiti ogre beast)

for m in "${meshes[@]}"; do
    if [[ ! -f "$meshes_src/$m.obj.gz" ]]; then
        echo "prepare: $meshes_src/$m.obj.gz is missing (set OCTOPROXY_MESHES to the meshes' folder)" >&2
        exit 1
    fi
done

echo "prepare: building the release binary with the bench (--features dev)"
cargo build --release --locked -p octoproxy-cli --features dev

rm -rf "$dir"
mkdir -p "$dir/gl" "$dir/meshes"
strip -o "$dir/octoproxy" target/release/octoproxy
for m in "${meshes[@]}"; do
    cp "$meshes_src/$m.obj.gz" "$dir/meshes/"
done

# The Vulkan loader for amd64, whatever this machine's architecture (the device's is x86-64).
lists=/tmp/octoproxy-gpu-check-apt
mkdir -p "$lists/partial"
apt=(-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 "-oDir::State::Lists=$lists")
apt-get "${apt[@]}" update >/dev/null
(cd "$dir/gl" && apt-get "${apt[@]}" download libvulkan1 libglvnd0 libglx0 libegl1 libgl1 libopengl0 libgles2 2>/dev/null)
ls "$dir"/gl/libvulkan1_*.deb >/dev/null

# The device tool carries at most 64 MiB with the working tree.
bytes=$(du -sb "$dir" | cut -f1)
if ((bytes > 48 * 1024 * 1024)); then
    echo "prepare: $dir is $((bytes / 1048576)) MiB, too large to carry" >&2
    exit 1
fi
echo "prepare: $dir holds $((bytes / 1024)) KiB:"
ls -l "$dir" "$dir/gl" "$dir/meshes"

if [[ "${1:-}" == "--check" ]]; then
    # The same command as on the device, on this machine's adapter, with few particles.
    out="${OUT:-target/gpu-check}"
    rm -rf "$out"
    mkdir -p "$out"
    OUT="$out" OCTOPROXY_CHECK_PARTICLES=20k OCTOPROXY_CHECK_LOCAL=1 bash xtask/gpu-check/run.sh
fi
