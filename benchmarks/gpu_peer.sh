#!/usr/bin/env bash
# This tree against a peer tree on a machine with a GPU and without Blender, same run (one command,
# under 8 minutes at 1920x1080 on an H100/H200):
#   1. the trace paths (benchmarks/bench_trace_path.py): the peer tree, this tree's compute path and
#      its fragment path alternating, and both paths with single rays on 4-wide and on binary nodes
#      (--layouts), hard lights (cold, light grids), then soft lights
#      (on the compute path a pixel's samples over lanes, and as packets),
#      with digests of the masks (equal digests: equal masks);
#   2. digests of every mask and image (tools/mask_digest.py) of both trees at 320x180;
#   3. Cycles on the same GPU as a peer, where this Python has bpy (the wheel is larger than what a
#      GPU machine here is sent: the script says when it is missing).
# Scenes are core scenes pickled where Blender is (tools/pickle_scenes.py): forest, clusters,
# city and scaling:triangles=1000000 for the timings, soft_lights for the soft ones, any others for
# the digests. On a GPU, judge the compute path: a compute-only chip (H100, H200) runs fragment
# work on a small part of the chip, so its fragment figures say little about an artist's GPU.
#
#   bash benchmarks/gpu_peer.sh PEER_TREE SCENES_DIR OUT_DIR [WxH]
#
# On a lent GPU machine: `bash benchmarks/gpu_prepare.sh PEER_COMMIT` here first; it prepares the
# loaders, wheels, scenes and peer tree and prints the one device command that runs this script.
set -euo pipefail
peer=$1 scenes=$(cd "$2" && pwd) out=$3 size=${4:-1920x1080}
py=${PYTHON:-python3}
mkdir -p "$out"
cd "$(dirname "$0")/.."
hard=()
for s in forest clusters city scaling_triangles_1000000; do
    [ -f "$scenes/$s.pkl.gz" ] && hard+=("$scenes/$s.pkl.gz")
done
echo "## hard lights, $size"
$py -m benchmarks.bench_trace_path --peer "$peer" --scenes "${hard[@]}" --size "$size" --frames 5 \
    --alternations 1 --layouts --configs "high cold" "high grids" --json "$out/paths_hard.json" | sed "s#$scenes/##g; s#.pkl.gz##g" | tee "$out/paths_hard.md"
if [ -f "$scenes/soft_lights.pkl.gz" ]; then
    echo "## soft lights, $size"
    $py -m benchmarks.bench_trace_path --peer "$peer" --scenes "$scenes/soft_lights.pkl.gz" "$scenes/forest.pkl.gz" \
        --size "$size" --frames 3 --alternations 1 --soft --configs "soft lanes" "soft packets" \
        --json "$out/paths_soft.json" \
        | sed "s#$scenes/##g; s#.pkl.gz##g" | tee "$out/paths_soft.md"
fi
all=$(ls "$scenes"/*.pkl.gz | grep -v 1000000 | paste -sd ';')
$py -m tools.mask_digest --tree "$peer" --scenes "$all" --resolution 320x180 --output "$out/digest_peer.json" >/dev/null
# (differing digests are reported, not fatal: the Cycles peer below still runs)
$py -m tools.mask_digest --scenes "$all" --resolution 320x180 --output "$out/digest_this.json" \
    --against "$out/digest_peer.json" | tail -n 20 || echo "digests: some variants differ from the peer's (above)"
if $py -c "import bpy" 2>/dev/null; then
    $py -m benchmarks.bench_cycles_frame --scenes forest clusters --size "$size" --alternations 1 --frames 3 \
        | tee "$out/cycles.md"
else
    echo "Cycles peer: no bpy in $py on this machine (not measured)" | tee "$out/cycles.md"
fi
