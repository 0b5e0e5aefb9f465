"""Does a sun-only scene pay for code it does not use? Times the ray-trace pass of the same sun
on the same geometry with the program the scene compiles (sun only, meshes only) and with every
optional path compiled in (local-light code is a separate program, so the 'all' variant forces
spheres, max distance and interlace-free local-light defines on), and the lighting pass of the
sun-only scene against the same scene plus unshadowed lights of every other type at zero power.

    .venv/bin/python -m benchmarks.bench_variants [--size 640x360] [--repeats 15]
"""
import argparse

import numpy as np

from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
from hybrid_shadow_addon.core.scene import Light
from hybrid_shadow_addon.core.settings import Settings


def scene_with_blocks(n=400, seed=0):
    from hybrid_shadow_addon.core.scene import Instances
    from tests.helpers.scenes import variant_scene

    s = variant_scene(("SUN",))
    rng = np.random.default_rng(seed)
    m = np.tile(np.eye(4), (n, 1, 1))
    m[:, :2, 3] = rng.uniform(-5, 5, (n, 2))
    m[:, [0, 1, 2], [0, 1, 2]] = rng.uniform(0.1, 0.4, (n, 3))
    extra = Instances(names=[f"b{i}" for i in range(n)], model_ids=np.ones(n, int), matrices=m)
    s.instances = Instances.concatenate([s.instances, extra])
    return s


def median_ms(pipe, scene, settings, w, h, key, repeats):
    pipe.render(scene, settings, w, h)
    return float(np.median([pipe.render(scene, settings, w, h).timings[key] for _ in range(repeats)]))


def main(argv=None):
    p = argparse.ArgumentParser()
    p.add_argument("--size", default="640x360")
    p.add_argument("--repeats", type=int, default=15)
    a = p.parse_args(argv)
    w, h = (int(v) for v in a.size.split("x"))
    scene = scene_with_blocks()
    pipe = Pipeline()
    pipe.set_scene(scene)
    st = Settings(mode="raytrace", hard=True)
    rows = []
    own = median_ms(pipe, scene, st, w, h, "shadow_ms", a.repeats)
    rt = pipe.shadow_pass("raytrace")
    defines_own = sorted(rt.last_defines)
    orig = rt.defines

    def all_on(settings, local):
        d = orig(settings, local)
        d.update(HS_HAS_SPHERES=1, HS_MAX_DISTANCE=1)
        return d
    rt.defines = all_on
    big = Settings(mode="raytrace", max_distance=1e9, hard=True)
    forced = median_ms(pipe, scene, big, w, h, "shadow_ms", a.repeats)
    rt.defines = orig
    rows.append(("ray trace, sun (own defines: " + ", ".join(defines_own) + ")", own))
    rows.append(("ray trace, sun, + sphere and max-distance code compiled in", forced))
    light_own = median_ms(pipe, scene, st, w, h, "lighting_ms", a.repeats)
    more = scene_with_blocks()
    for t in ("POINT", "SPOT", "AREA"):
        more.lights.append(Light(t.lower(), t, power=0.0, use_shadow=False))
    pipe.set_scene(more)
    light_more = median_ms(pipe, more, st, w, h, "lighting_ms", a.repeats)
    rows.append(("lighting, sun only", light_own))
    rows.append(("lighting, sun + unshadowed point, spot, area (0 W)", light_more))
    pipe.release()
    print(f"| variant ({w}x{h}, {len(scene.instances)} instances, median of {a.repeats}) | ms |")
    print("|---|---|")
    for name, ms in rows:
        print(f"| {name} | {ms:.2f} |")


if __name__ == "__main__":
    main()
