#!/usr/bin/env bash
# This tree against a peer tree on a machine with a GPU and without Blender, same run:
#   1. frame timings per pass (benchmarks/bench_frame.py: trees alternating), hard and soft lights;
#   2. digests of every mask and image (tools/mask_digest.py) of both trees: they must be equal.
# Scenes are core scenes pickled where Blender is (tools/pickle_scenes.py).
#
#   bash benchmarks/gpu_peer.sh PEER_TREE SCENES_DIR OUT_DIR [WxH]
set -euo pipefail
peer=$1 scenes=$(cd "$2" && pwd) out=$3 size=${4:-1920x1080}
py=${PYTHON:-python3}
mkdir -p "$out"
cd "$(dirname "$0")/.."
bench=("$scenes/forest.pkl.gz" "$scenes/clusters.pkl.gz" "$scenes/city.pkl.gz")
echo "## hard lights, $size"
$py benchmarks/bench_frame.py --peer "$peer" --scenes "${bench[@]}" --size "$size" --frames 7 --alternations 2 \
    | sed "s#$scenes/##g; s#.pkl.gz##g" | tee "$out/frame_hard.md"
echo "## soft lights, $size"
$py benchmarks/bench_frame.py --peer "$peer" --scenes "$scenes/soft_lights.pkl.gz" \
    --size "$size" --soft --frames 4 --alternations 1 | sed "s#$scenes/##g; s#.pkl.gz##g" | tee "$out/frame_soft.md"
all=$(ls "$scenes"/*.pkl.gz | paste -sd ';')
$py tools/mask_digest.py --tree "$peer" --scenes "$all" --resolution 320x180 --output "$out/digest_peer.json" >/dev/null
$py tools/mask_digest.py --scenes "$all" --resolution 320x180 --output "$out/digest_this.json" \
    --against "$out/digest_peer.json" | tail -n 20
