#!/usr/bin/env bash
# The GPU device check, run on the device machine from the repository root with .gpu-check/
# carried (see prepare.sh beside this file): installs the carried Vulkan loader (and libglvnd,
# which NVIDIA's Vulkan driver, inside libGLX_nvidia, needs), finds the
# NVIDIA driver, and runs the wgpu bench on the bench scenes at 1M, 3M and 10M particles with
# the GPU floor and the plain step's workgroup size swept from 32 to 256, the split step at the
# default size (timed by the bench beside the single dispatch), and the particle-particle pass
# at 1M. Everything lands in $OUT: results.json (what docs/bench/gpu/
# commits), results.md, the log and the driver's report. About 2.5 minutes on an H200.
#
# Not the scene cases: on NVIDIA's driver (580) the scene kernel took 154 s and 229 s to build
# (two runs, 2026-12-04), which alone would use most of the 6 minutes the check may take.
set -uo pipefail
dir=.gpu-check
out="${OUT:?OUT must name the folder results go to}"
particles="${OCTOPROXY_CHECK_PARTICLES:-1m}"
if [[ -z "${OCTOPROXY_CHECK_LOCAL:-}" ]]; then
    for f in "$dir"/gl/*.deb; do dpkg -x "$f" /; done
    ldconfig
    icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
    [[ -f "$icd" ]] && export VK_DRIVER_FILES="$icd"
    nvidia-smi >"$out/nvidia-smi.txt" 2>&1 || true
    # What the loader will find, for a run that finds no adapter.
    { cat "$icd"; ldconfig -p | grep -E 'libvulkan|libGLX|libGLdispatch'; } >>"$out/nvidia-smi.txt" 2>&1
fi
start=$SECONDS
# Well inside the device check's 6 minutes: the bench stops at 5.
timeout 300 "$dir/octoproxy" bench --backends wgpu \
    --scenes bunny,nefertiti,ogre,beast,nefertiti-6.4m,particles-pile,particles-cloud \
    --particles "$particles" --gpu-particles 3m,10m --workgroup-sizes 32,64,128,256 \
    --gpu-repeats 3 --no-scene-api --meshes "$dir/meshes" --out "$out" 2>&1 | tee "$out/log.txt"
rc=$?
echo "gpu-check: the bench ended with status $rc after $((SECONDS - start)) s" | tee -a "$out/log.txt"
exit $rc
