// Refinement, classify step: per full-resolution pixel and light, take the answer of the coarse
// rays around it, or ask for the pixel's own ray.
//
// A pixel needs no ray when shadow_ray_prelude decides it (background, beyond the max distance,
// facing away, out of reach: exactly what the full-resolution trace writes), when it is a coarse
// sample itself (or, HS_INTERLACE, has this frame's ray or an up-to-date history), or when its
// cell agrees (refine_cells.glsl), all four samples can stand for it (refine_geometry.glsl) and
// it does not graze the light (cosine to the light at least u_grazing). Otherwise it gets its
// own ray: gl_FragDepth 0 (the refine draws then run only there, under the depth test).
// HS_GROUP_VOTE (passes/refine.py, rule group): every pixel of a SIMD group that holds a
// marked pixel is marked too, unless a ray would only repeat what it knows (decided by the
// prelude, a coarse sample, an interlaced ray or history). Where the group is a fixed block
// of pixels in both draws (llvmpipe's 4x2), the trace pays each group its slowest lane
// anyway, and the group's other pixels get their exact answer for no extra time. (Mesa 22.3's
// vote gives about 1 % of the pixels of voting groups their own value instead: fewer marks
// there, never a wrong answer; an unmarked pixel keeps what it had without the vote.)

#ifdef VERTEX_SHADER
#include "common/fullscreen.glsl"
#endif

#ifdef FRAGMENT_SHADER
#ifdef HS_GROUP_VOTE
#extension GL_ARB_shader_group_vote : require
#endif
#include "common/camera.glsl"
#include "common/gbuffer.glsl"
#include "common/shadow_ray.glsl"
#include "common/refine_grid.glsl"

uniform sampler2D u_cells;      // refine_cells.glsl
uniform sampler2D u_geometry;   // refine_geometry.glsl
uniform float u_grazing;

layout(location = 0) out float o_mask;

void main()
{
    ivec2 pix = ivec2(gl_FragCoord.xy);
    vec3 p, n, ns, to_light;
    float depth;
    float value = shadow_ray_prelude(pix, p, n, ns, depth, to_light);
    if (value < 0.0) {
#ifdef HS_INTERLACE
        value = texelFetch(u_coarse, pix, 0).r;            // this frame's ray or history
#else
        ivec2 own = pix / u_scale;
        if (sample_pixel(own) == pix) value = texelFetch(u_coarse, own, 0).r;
#endif
    }
    bool known = value >= 0.0;
    if (value < 0.0) {
        ivec2 cell = sample_cell(pix);
        bool inside = all(greaterThanEqual(cell, ivec2(0))) && all(lessThan(cell, textureSize(u_cells, 0)));
        float v = inside ? texelFetch(u_cells, cell, 0).r : -1.0;
        bool stands = texelFetch(u_geometry, pix, 0).r == 15.0;
        if (stands && dot(n, normalize(to_light)) >= u_grazing) value = v;
    }
    bool need = value < 0.0;
#ifdef HS_GROUP_VOTE
    need = anyInvocationARB(need) && !known;   // (uniform control flow: every lane votes)
#endif
    o_mask = need ? 1.0 : value;
    gl_FragDepth = need ? 0.0 : 1.0;
}
#endif
