// Pass 3: deferred lighting. Batch 0 writes ambient (albedo x world colour), every unmasked
// light and up to 8 masked lights; further batches add 8 masked lights each (additive blend).
// An emitter (specular < 0 in the G-buffer) shows its albedo, its emission, and nothing else.
// HS_MASKS: the masked lights of the batch (a program per count), the first HS_MASKS_POINT of
// them lights other than sized area lights; HS_FIRST_BATCH, and with it HS_UNMASKED_POINT and
// HS_UNMASKED_AREA where there are such unmasked lights (rows [0, u_unmasked_split) and
// [u_unmasked_split, u_unmasked_end)). Each kind has a loop of its own,
// present only where the kind is (llvmpipe runs the body of a loop whose range is empty once,
// masked, and both sides of a branch on the kind: an area light's polygon cost every light).
// HS_LINKING: a light lights only the pixels whose instance is in its receiver set
// (common/linking.glsl; hs_link_lights_tex: each table row's receiver set).
#include "common/camera.glsl"
#include "common/gbuffer.glsl"
#include "common/lights.glsl"
#include "common/linking.glsl"

#ifdef VERTEX_SHADER
#include "common/fullscreen.glsl"
#endif

#ifdef FRAGMENT_SHADER
#define MAX_MASKS 8
uniform int u_unmasked_split;
uniform int u_unmasked_end;
uniform int u_masked_rows[MAX_MASKS];
uniform sampler2D u_masks[MAX_MASKS];
uniform vec3 u_world_color;
uniform int u_specular;
uniform int u_transparent;
layout(location = 0) out vec4 o_color;
#ifdef HS_LINKING
uniform isampler2D hs_link_lights_tex;   // texel (r, 0): the receiver set of table row r, -1: none
#define HS_LINK_GAIN(r) (hs_link_receives(inst, texelFetch(hs_link_lights_tex, ivec2(r, 0), 0).x) ? 1.0 : 0.0)
#else
#define HS_LINK_GAIN(r) 1.0
#endif

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
        // material w < 0: a holdout's pixel (shaders/gbuffer.glsl), a hole whatever the film
        bool hole = texelFetch(u_gb_material, pix, 0).w < 0.0;
        o_color = (u_transparent == 0 && !hole) ? vec4(u_world_color, 1.0) : vec4(0.0);
#else
        o_color = vec4(0.0);
#endif
        return;
    }
    vec3 p = pos.xyz;
    vec3 n = texelFetch(u_gb_shading, pix, 0).xyz;
    vec3 albedo = texelFetch(u_gb_albedo, pix, 0).rgb;
    vec4 mat = texelFetch(u_gb_material, pix, 0);
    if (mat.x < 0.0) {   // an emitter (passes/gbuffer.py EMITTER_SPECULAR): its colour, unlit
#ifdef HS_FIRST_BATCH
        o_color = vec4(albedo, 1.0);
#else
        o_color = vec4(0.0);
#endif
        return;
    }
#ifdef HS_LINKING
    int inst = int(mat.z + 0.5);
#endif
    vec3 v = view_vector(p);
    vec3 c = vec3(0.0);
#ifdef HS_FIRST_BATCH
    c = albedo * u_world_color;
#ifdef HS_UNMASKED_POINT
    for (int r = 0; r < u_unmasked_split; ++r) {
        c += HS_LINK_GAIN(r) * point_contribution(r, p, n, v, albedo, mat.x, mat.y, u_specular);
    }
#endif
#ifdef HS_UNMASKED_AREA
    for (int r = u_unmasked_split; r < u_unmasked_end; ++r) {
        c += HS_LINK_GAIN(r) * area_contribution(r, p, n, v, albedo, mat.x, mat.y, u_specular);
    }
#endif
#endif
    // this batch's HS_MASKS masks, read with constant indices (a software rasteriser indexes a
    // sampler array by a variable through every sampler of it), then its lights in one loop
    // (one copy of the lighting code, whose iterations past the batch are not run)
    float mv[MAX_MASKS];
#define HS_MASK_AT(K) mv[K] = (K < HS_MASKS) ? mask_at(K, pix) : 0.0;
    HS_MASK_AT(0) HS_MASK_AT(1) HS_MASK_AT(2) HS_MASK_AT(3) HS_MASK_AT(4) HS_MASK_AT(5) HS_MASK_AT(6) HS_MASK_AT(7)
#if HS_MASKS_POINT > 0
    for (int k = 0; k < HS_MASKS_POINT; ++k) {
        float m = mv[k] * HS_LINK_GAIN(u_masked_rows[k]);
        if (m <= 0.0) continue;
        c += m * point_contribution(u_masked_rows[k], p, n, v, albedo, mat.x, mat.y, u_specular);
    }
#endif
#if HS_MASKS > HS_MASKS_POINT
    for (int k = HS_MASKS_POINT; k < HS_MASKS; ++k) {
        float m = mv[k] * HS_LINK_GAIN(u_masked_rows[k]);
        if (m <= 0.0) continue;
        c += m * area_contribution(u_masked_rows[k], p, n, v, albedo, mat.x, mat.y, u_specular);
    }
#endif
#ifdef HS_FIRST_BATCH
    o_color = vec4(c, 1.0);
#else
    o_color = vec4(c, 0.0);
#endif
}
#endif
