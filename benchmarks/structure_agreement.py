"""Agreement of the two acceleration structures: for every stiff scene (200x150) and forest and
clusters (320x180), the share of pixels whose ray-traced `high` mask differs between `grid` and
`bvh` (worst light). Usage: ``.venv/bin/python -m benchmarks.structure_agreement``"""
import sys

import numpy as np

from hybrid_shadow_addon.blender.load import builtin_scenes, load_scene
from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
from hybrid_shadow_addon.core.settings import Settings


def main() -> int:
    pipe = Pipeline()
    print("| scene | pixels differing, worst light |\n|---|---:|")
    for name in [n for n in builtin_scenes() if n.startswith("stiff/")] + ["forest", "clusters"]:
        scene = load_scene(name)
        w, h = (200, 150) if name.startswith("stiff/") else (320, 180)
        masks = {}
        for structure in ("grid", "bvh"):
            frame = pipe.render(scene, Settings(structure=structure, hard=True), w, h)
            masks[structure] = [frame.mask_array(li) for li in frame.lights]
        worst = 0.0
        for a, b in zip(masks["grid"], masks["bvh"]):
            valid = ~np.isnan(a) & ~np.isnan(b)
            worst = max(worst, 100.0 * float(np.mean(np.abs(a[valid] - b[valid]) > 0.5)))
        print(f"| {name} | {worst:.3f}% |", flush=True)
    pipe.release()
    return 0


if __name__ == "__main__":
    sys.exit(main())
