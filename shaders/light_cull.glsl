// Bounds of the visible surfaces, per block of HS_CULL_BLOCK x HS_CULL_BLOCK pixels: the box of
// the points the shadow rays would start from (shadow_ray.glsl's surface_point, bake space),
// over the block's pixels with geometry (within the max distance, with a margin: a pixel left
// out must be beyond it in shadow_ray_prelude too). raytrace.py reads the boxes back and leaves
// out a light none of them reaches (passes/light_cull.py).
// Outputs (RGBA32F, one texel per block): o_lo = (min xyz, 1 if the block has such a pixel else
// 0), o_hi = (max xyz, 0).

#ifdef VERTEX_SHADER
#include "common/fullscreen.glsl"
#endif

#ifdef FRAGMENT_SHADER
#include "common/camera.glsl"
#include "common/gbuffer.glsl"
#include "common/shadow_ray.glsl"

uniform ivec2 u_full_size;
layout(location = 0) out vec4 o_lo;
layout(location = 1) out vec4 o_hi;

void main()
{
    ivec2 b0 = ivec2(gl_FragCoord.xy) * HS_CULL_BLOCK;
    vec3 lo = vec3(3.0e38), hi = vec3(-3.0e38);
    float any_px = 0.0;
    for (int y = 0; y < HS_CULL_BLOCK; ++y) {
        for (int x = 0; x < HS_CULL_BLOCK; ++x) {
            ivec2 px = min(b0 + ivec2(x, y), u_full_size - 1);
            float depth = texelFetch(u_gb_depth, px, 0).r;
            vec3 p = surface_point(px, depth);
            bool keep = depth != 0.0;   // (0 on the background; at least the clip start on geometry)
#ifdef HS_MAX_DISTANCE
            keep = keep && !(distance(p, u_cam_bake) > u_max_distance * 1.0001 + 1.0e-4);
#endif
            lo = keep ? min(lo, p) : lo;
            hi = keep ? max(hi, p) : hi;
            any_px = keep ? 1.0 : any_px;
        }
    }
    o_lo = vec4(lo, any_px);
    o_hi = vec4(hi, 0.0);
}
#endif
