// Edge-aware (joint bilateral) upsample of a reduced-resolution shadow mask to full resolution.
// Each full-res pixel blends the 4x4 nearest mask texels, weighted by distance (tent in mask
// texels), by how far each texel's surface point lies from this pixel's tangent plane, and by
// normal agreement: shadows stay sharp along depth and crease edges instead of blocky.
#include "common/camera.glsl"
#include "common/gbuffer.glsl"

#ifdef VERTEX_SHADER
#include "common/fullscreen.glsl"
#endif

#ifdef FRAGMENT_SHADER
uniform sampler2D u_mask;       // reduced resolution, R32F
uniform int u_scale;            // 2 or 4
uniform float u_plane_sigma;    // relative to the view depth (e.g. 0.02)
uniform float u_normal_power;   // e.g. 16
uniform int u_nearest;          // 1: plain nearest (the thesis' blocky masks)
layout(location = 0) out float o_mask;

void main() {
    ivec2 pix = ivec2(gl_FragCoord.xy);
    ivec2 full = ivec2(u_resolution);
    ivec2 msize = textureSize(u_mask, 0);
    vec4 pos = texelFetch(u_gb_position, pix, 0);
    if (pos.w < 0.5) { o_mask = 1.0; return; }
    vec2 f = (vec2(pix) - vec2(u_scale / 2)) / float(u_scale);   // continuous mask coordinate
    if (u_nearest == 1) {
        o_mask = texelFetch(u_mask, clamp(ivec2(floor(f + 0.5)), ivec2(0), msize - 1), 0).r;
        return;
    }
    vec3 n = texelFetch(u_gb_normal, pix, 0).xyz;
    float depth = max(texelFetch(u_gb_depth, pix, 0).r, 1e-6);
    ivec2 base = ivec2(floor(f));
    float sum = 0.0, wsum = 0.0;
    float best_d = 1e30, best_v = 1.0;
    for (int dy = -1; dy <= 2; ++dy) {
        for (int dx = -1; dx <= 2; ++dx) {
            ivec2 q = base + ivec2(dx, dy);
            if (any(lessThan(q, ivec2(0))) || any(greaterThanEqual(q, msize))) continue;
            ivec2 src = mask_source_pixel(q, u_scale, full);
            vec4 sp = texelFetch(u_gb_position, src, 0);
            if (sp.w < 0.5) continue;
            float value = texelFetch(u_mask, q, 0).r;
            vec2 dd = abs(vec2(q) - f);
            float ws = max(1.0 - dd.x, 0.0) * max(1.0 - dd.y, 0.0) + 1e-3;   // bilinear (+ a little of the 4x4 ring)
            vec3 sn = texelFetch(u_gb_normal, src, 0).xyz;
            float plane = abs(dot(n, sp.xyz - pos.xyz)) / (u_plane_sigma * depth);
            float wz = exp(-plane * plane);
            float wn = pow(max(dot(n, sn), 0.0), u_normal_power);
            float w = ws * wz * wn;
            sum += w * value;
            wsum += w;
            float dist = dot(dd, dd) + plane;
            if (dist < best_d) { best_d = dist; best_v = value; }
        }
    }
    o_mask = wsum > 1e-6 ? sum / wsum : best_v;
}
#endif
