// Pass 3: deferred lighting. Batch 0 writes ambient (albedo x world colour), every unmasked
// light and up to 8 masked lights; further batches add 8 masked lights each (additive blend).
// Each kind of light (lights.glsl HS_KIND_*) is lit in a loop of its own, compiled only where the
// batch has that kind (llvmpipe runs the body of a loop whose range is empty once, masked, and
// both sides of a branch on the kind: one loop for all cost every light an area light's code).
// HS_MASKS: the masked lights of the batch (a program per count), kind by kind: kind 0 up to
// HS_MB1, kind 1 up to HS_MB2, kind 2 up to HS_MB3, kind 3 up to HS_MASKS. HS_FIRST_BATCH, and with
// it HS_UNMASKED_K0..3 for the kinds the unmasked lights have (kind k: rows [u_ubk, u_ubk+1)).
#include "common/camera.glsl"
#include "common/gbuffer.glsl"
#include "common/lights.glsl"

#ifdef VERTEX_SHADER
#include "common/fullscreen.glsl"
#endif

#ifdef FRAGMENT_SHADER
#define MAX_MASKS 8
uniform int u_ub0, u_ub1, u_ub2, u_ub3, u_ub4;
uniform int u_masked_rows[MAX_MASKS];
uniform sampler2D u_masks[MAX_MASKS];
uniform vec3 u_world_color;
uniform int u_specular;
uniform int u_transparent;
layout(location = 0) out vec4 o_color;

float mask_at(int k, ivec2 pix) {
    ivec2 size = textureSize(u_masks[k], 0);
    ivec2 full = ivec2(u_resolution);
    ivec2 q = (size == full) ? pix : min(pix * size / full, size - 1);
    return texelFetch(u_masks[k], q, 0).r;
}

void main() {
    ivec2 pix = ivec2(gl_FragCoord.xy);
    vec4 pos = texelFetch(u_gb_position, pix, 0);
    if (pos.w < 0.5) {
#ifdef HS_FIRST_BATCH
        o_color = u_transparent == 0 ? vec4(u_world_color, 1.0) : vec4(0.0);
#else
        o_color = vec4(0.0);
#endif
        return;
    }
    vec3 p = pos.xyz;
    vec3 n = texelFetch(u_gb_shading, pix, 0).xyz;
    vec3 albedo = texelFetch(u_gb_albedo, pix, 0).rgb;
    vec2 mat = texelFetch(u_gb_material, pix, 0).xy;
    vec3 v = view_vector(p);
    vec3 c = vec3(0.0);
#ifdef HS_FIRST_BATCH
    c = albedo * u_world_color;
    // (one line each: #version 410 has no line continuation)
#define HS_LIGHTS_UNMASKED(B, E, KIND) for (int r = B; r < E; ++r) c += light_contribution(r, p, n, v, albedo, mat.x, mat.y, u_specular, KIND);
#ifdef HS_UNMASKED_K0
    HS_LIGHTS_UNMASKED(u_ub0, u_ub1, 0)
#endif
#ifdef HS_UNMASKED_K1
    HS_LIGHTS_UNMASKED(u_ub1, u_ub2, 1)
#endif
#ifdef HS_UNMASKED_K2
    HS_LIGHTS_UNMASKED(u_ub2, u_ub3, 2)
#endif
#ifdef HS_UNMASKED_K3
    HS_LIGHTS_UNMASKED(u_ub3, u_ub4, 3)
#endif
#endif
    // this batch's HS_MASKS masks, read with constant indices (a software rasteriser indexes a
    // sampler array by a variable through every sampler of it), then its lights kind by kind
    // (one copy of each kind's code, whose iterations past the batch are not run)
    float mv[MAX_MASKS];
#define HS_MASK_AT(K) mv[K] = (K < HS_MASKS) ? mask_at(K, pix) : 0.0;
    HS_MASK_AT(0) HS_MASK_AT(1) HS_MASK_AT(2) HS_MASK_AT(3) HS_MASK_AT(4) HS_MASK_AT(5) HS_MASK_AT(6) HS_MASK_AT(7)
#define HS_LIGHTS_MASKED(B, E, KIND) for (int k = B; k < E; ++k) { float m = mv[k]; if (!(m <= 0.0)) c += m * light_contribution(u_masked_rows[k], p, n, v, albedo, mat.x, mat.y, u_specular, KIND); }
#if HS_MB1 > 0
    HS_LIGHTS_MASKED(0, HS_MB1, 0)
#endif
#if HS_MB2 > HS_MB1
    HS_LIGHTS_MASKED(HS_MB1, HS_MB2, 1)
#endif
#if HS_MB3 > HS_MB2
    HS_LIGHTS_MASKED(HS_MB2, HS_MB3, 2)
#endif
#if HS_MASKS > HS_MB3
    HS_LIGHTS_MASKED(HS_MB3, HS_MASKS, 3)
#endif
#ifdef HS_FIRST_BATCH
    o_color = vec4(c, 1.0);
#else
    o_color = vec4(c, 0.0);
#endif
}
#endif
