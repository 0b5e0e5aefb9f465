// Bounds of the visible surfaces, per block of HS_CULL_BLOCK x HS_CULL_BLOCK pixels: the box of
// the points the shadow rays would start from (shadow_ray.glsl's surface_point, bake space),
// over the block's pixels with geometry (within the max distance, with a margin: a pixel left
// out must be beyond it in shadow_ray_prelude too). raytrace.py reads the boxes back and leaves
// out a light none of them reaches (passes/light_cull.py).
// Outputs (RGBA32F, one texel per block), two boxes: the points nearer than the middle of the
// block's depth range and the others; o_lo_* = (min xyz, 1 if the box has a point else 0),
// o_hi_* = (max xyz, 0).

#ifdef VERTEX_SHADER
#include "common/fullscreen.glsl"
#endif

#ifdef FRAGMENT_SHADER
#include "common/camera.glsl"
#include "common/gbuffer.glsl"
#include "common/shadow_ray.glsl"

uniform ivec2 u_full_size;
layout(location = 0) out vec4 o_lo_near;
layout(location = 1) out vec4 o_hi_near;
layout(location = 2) out vec4 o_lo_far;
layout(location = 3) out vec4 o_hi_far;

bool hs_cull_keep(float depth, vec3 p)
{
    bool keep = depth != 0.0;   // (0 on the background; at least the clip start on geometry)
#ifdef HS_MAX_DISTANCE
    keep = keep && !(distance(p, u_cam_bake) > u_max_distance * 1.0001 + 1.0e-4);
#endif
    return keep;
}

void main()
{
    ivec2 b0 = ivec2(gl_FragCoord.xy) * HS_CULL_BLOCK;
    // the block's depth range: its points go to two boxes, nearer and farther than the middle
    // (a block on a silhouette spans a near object and what lies far behind it)
    float dlo = 3.0e38, dhi = 0.0;
    for (int y = 0; y < HS_CULL_BLOCK; ++y) {
        for (int x = 0; x < HS_CULL_BLOCK; ++x) {
            float depth = texelFetch(u_gb_depth, min(b0 + ivec2(x, y), u_full_size - 1), 0).r;
            dlo = depth != 0.0 ? min(dlo, depth) : dlo;
            dhi = max(dhi, depth);
        }
    }
    float mid = 0.5 * (dlo + dhi);
    vec3 lo0 = vec3(3.0e38), hi0 = vec3(-3.0e38), lo1 = vec3(3.0e38), hi1 = vec3(-3.0e38);
    float any0 = 0.0, any1 = 0.0;
    for (int y = 0; y < HS_CULL_BLOCK; ++y) {
        for (int x = 0; x < HS_CULL_BLOCK; ++x) {
            ivec2 px = min(b0 + ivec2(x, y), u_full_size - 1);
            float depth = texelFetch(u_gb_depth, px, 0).r;
            vec3 p = surface_point(px, depth);
            bool keep = hs_cull_keep(depth, p);
            bool near = depth <= mid;
            lo0 = keep && near ? min(lo0, p) : lo0;
            hi0 = keep && near ? max(hi0, p) : hi0;
            any0 = keep && near ? 1.0 : any0;
            lo1 = keep && !near ? min(lo1, p) : lo1;
            hi1 = keep && !near ? max(hi1, p) : hi1;
            any1 = keep && !near ? 1.0 : any1;
        }
    }
    o_lo_near = vec4(lo0, any0);
    o_hi_near = vec4(hi0, 0.0);
    o_lo_far = vec4(lo1, any1);
    o_hi_far = vec4(hi1, 0.0);
}
#endif
