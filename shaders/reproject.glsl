// Reuse of shadow visibility across camera moves (passes/reproject.py): each pixel finds its
// surface point in the previous frame's image and keeps what that frame knew there where the
// surface is the same.
//
// STORE: the G-buffer kept for the next frame (o_geo: world xyz, instance index + 1, 0 on
// background; o_nrm: geometric normal, footprint of a pixel on the surface).
// MARK (hard lights): per pixel, the answer without a ray (shadow_ray_prelude), else the previous
// mask at the previous frame's pixel of its world position where hs_history_pixel accepts it and
// the previous mask's 3x3 neighbourhood there is all 0 or all 1 (no shadow edge) and its samples
// (u_still, the same camera: the same pixel, edge or not) were no sparser than u_spacing_ratio
// of this frame's pixel footprint (a zoom in retraces, so a shadow thinner than the old spacing
// is found); else a mark for a ray (gl_FragDepth 0). o_spacing: the surface spacing of the
// samples the value stands on, positive where it was reused, negative (minus this frame's
// footprint) where it is this frame's.
// HISTORY: hs_history_pixel of each pixel but for the edited boxes (light-independent: once a
// frame, for every hard light's MARK), -1 where it has none.
// FRESH: the spacing of a mask traced whole (minus the footprint).
// COUNT: discards all but the reused pixels (an occlusion query counts them).
// SOFT: the previous frame's accumulated sums (RG: weighted visibility, weight; B: samples) at
// the previous pixel where hs_history_pixel accepts it, else 0 (the pixel starts over).
//
// hs_history_pixel rejects: background, a point behind or outside the previous view, another
// instance there, normals apart (u_normal_cos), a point off the previous sample's surface by more
// than u_pos_tol footprints (6 times that / the view's cosine along it), a grazing view in
// either frame (u_view_cos), a point beyond the previous frame's max distance, and a shadow
// segment (or a soft light's cone, widened by u_pad_abs + u_pad_slope x distance) that meets
// one of the u_boxes edited boxes (bake space).

#ifdef VERTEX_SHADER
#include "common/fullscreen.glsl"
#endif

#ifdef FRAGMENT_SHADER
#include "common/camera.glsl"
#include "common/gbuffer.glsl"
#ifndef STORE
#include "common/shadow_ray.glsl"
#endif

#define HS_MAX_BOXES 32

// A pixel's footprint on a surface facing the camera at view depth `depth`.
float hs_footprint(float depth)
{
    float w = (u_viewplane.y - u_viewplane.x) / u_resolution.x;
    return u_ortho == 1 ? w : w * depth / u_clip_start;
}

#ifdef STORE
layout(location = 0) out vec4 o_geo;
layout(location = 1) out vec4 o_nrm;

void main()
{
    ivec2 px = ivec2(gl_FragCoord.xy);
    vec4 pos = texelFetch(u_gb_position, px, 0);
    if (pos.w == 0.0) { o_geo = vec4(0.0); o_nrm = vec4(0.0); return; }
    o_geo = vec4(pos.xyz, texelFetch(u_gb_material, px, 0).z + 1.0);
    o_nrm = vec4(texelFetch(u_gb_normal, px, 0).xyz, hs_footprint(texelFetch(u_gb_depth, px, 0).r));
}
#else

uniform sampler2D u_prev_geo;   // STORE's outputs of the previous frame
uniform sampler2D u_prev_nrm;
uniform mat4 u_prev_clip;       // the previous camera's clip_from_rel
uniform vec3 u_cam_delta;       // this camera's position - the previous one's (float64 on the CPU)
uniform float u_pos_tol;
uniform float u_normal_cos;
uniform float u_view_cos;
uniform int u_same_instance;    // 1: another instance there rejects (0 only in the tests)
uniform int u_boxes;
uniform vec3 u_box_min[HS_MAX_BOXES];
uniform vec3 u_box_max[HS_MAX_BOXES];
uniform float u_pad_abs;
uniform float u_pad_slope;

// Whether the segment from p towards the light (u_light_vec; a sun: the ray) can meet box i.
bool hs_segment_meets(vec3 p, int i)
{
    vec3 c = 0.5 * (u_box_min[i] + u_box_max[i]);
    vec3 pad = vec3(u_pad_abs + u_pad_slope * (distance(p, c) + distance(u_box_max[i], c)));
    vec3 lo = u_box_min[i] - pad, hi = u_box_max[i] + pad;
#ifdef HS_LIGHT_LOCAL
    vec3 d = u_light_vec - p;
    float tmax = 1.0;
#else
    vec3 d = u_light_vec;
    float tmax = 1.0e30;
#endif
    vec3 inv = 1.0 / d;     // (IEEE: a zero component gives +-inf, the slabs still work)
    vec3 t0 = (lo - p) * inv, t1 = (hi - p) * inv;
    vec3 tn = min(t0, t1), tf = max(t0, t1);
    float enter = max(max(tn.x, tn.y), max(tn.z, 0.0));
    float leave = min(min(tf.x, tf.y), min(tf.z, tmax));
    return enter <= leave;
}

vec2 hs_win;    // hs_history_pixel's point in the previous frame's window (pixels)

// The previous frame's pixel that holds pixel px's surface point, or (-1, -1).
ivec2 hs_history_pixel(ivec2 px, out float footprint)
{
    footprint = 0.0;
    vec4 pos = texelFetch(u_gb_position, px, 0);
    if (pos.w == 0.0) return ivec2(-1);
    float depth = texelFetch(u_gb_depth, px, 0).r;
    footprint = hs_footprint(depth);
    vec3 n = texelFetch(u_gb_normal, px, 0).xyz;
    float cv = abs(dot(n, view_vector(pos.xyz)));
    if (cv < u_view_cos) return ivec2(-1);
    vec3 p_bake = surface_point(px, depth);
    vec3 p_rel = p_bake - u_cam_bake + u_cam_delta;    // relative to the previous camera
    vec4 clip = u_prev_clip * vec4(p_rel, 1.0);
    if (!(clip.w > 0.0)) return ivec2(-1);
    vec2 win = (clip.xy / clip.w * 0.5 + 0.5) * vec2(textureSize(u_prev_geo, 0));
    hs_win = win;
    ivec2 q = ivec2(floor(win));
    ivec2 lim = textureSize(u_prev_geo, 0) - 1;
    if (any(lessThan(q, ivec2(1))) || any(greaterThanEqual(q, lim))) return ivec2(-1);
    vec4 g = texelFetch(u_prev_geo, q, 0);
    if (g.w == 0.0 || (u_same_instance == 1 && g.w != texelFetch(u_gb_material, px, 0).z + 1.0)) return ivec2(-1);
    vec4 pn = texelFetch(u_prev_nrm, q, 0);
    if (dot(pn.xyz, n) < u_normal_cos) return ivec2(-1);
    vec3 off = pos.xyz - g.xyz;
    float fp = max(footprint, pn.w);
    if (abs(dot(off, n)) > u_pos_tol * fp || length(off) > 6.0 * u_pos_tol * fp / cv) return ivec2(-1);
    vec3 prev_view = normalize(-p_rel);
    if (u_ortho == 0 && abs(dot(n, prev_view)) < u_view_cos) return ivec2(-1);
#ifdef HS_MAX_DISTANCE
    if (length(p_rel) > u_max_distance * 0.999) return ivec2(-1);
#endif
    for (int i = 0; i < u_boxes; ++i)
        if (hs_segment_meets(p_bake, i)) return ivec2(-1);
    return q;
}

#ifdef SOFT
uniform sampler2D u_prev_sums;
uniform float u_keep;           // the share of the carried sums kept (older samples fade)
layout(location = 0) out vec4 o_sums;

// The sums at the point itself, bilinear over the previous pixels around it that hold the same
// surface (instance, normal, plane): taking the nearest pixel's would let the sums lag behind a
// slow move, frame after frame.
void main()
{
    ivec2 px = ivec2(gl_FragCoord.xy);
    float fp;
    ivec2 q = hs_history_pixel(px, fp);
    if (q.x < 0) { o_sums = vec4(0.0); return; }
    vec3 pos = texelFetch(u_gb_position, px, 0).xyz;
    vec3 n = texelFetch(u_gb_normal, px, 0).xyz;
    float inst = texelFetch(u_gb_material, px, 0).z + 1.0;
    vec2 f = hs_win - 0.5;
    ivec2 b = ivec2(floor(f));
    vec2 t = f - vec2(b);
    vec4 sum = vec4(0.0);
    float wsum = 0.0;
    for (int k = 0; k < 4; ++k) {
        ivec2 o = ivec2(k & 1, k >> 1);
        ivec2 r = b + o;
        float w = (o.x == 1 ? t.x : 1.0 - t.x) * (o.y == 1 ? t.y : 1.0 - t.y);
        vec4 g = texelFetch(u_prev_geo, r, 0);
        if (w <= 0.0 || g.w != inst || dot(texelFetch(u_prev_nrm, r, 0).xyz, n) < u_normal_cos
            || abs(dot(g.xyz - pos, n)) > u_pos_tol * fp) continue;
        sum += w * texelFetch(u_prev_sums, r, 0);
        wsum += w;
    }
    o_sums = u_keep * (wsum > 0.0 ? sum / wsum : texelFetch(u_prev_sums, q, 0));
}
#elif defined(HISTORY)
layout(location = 0) out vec2 o_q;

void main()
{
    float fp;
    o_q = vec2(hs_history_pixel(ivec2(gl_FragCoord.xy), fp));
}
#elif defined(FRESH)
out float o_spacing;

void main()
{
    ivec2 px = ivec2(gl_FragCoord.xy);
    o_spacing = -max(hs_footprint(texelFetch(u_gb_depth, px, 0).r), 1e-30);
}
#elif defined(COUNT)
uniform sampler2D u_spacing;
out float o_mask;

void main()
{
    if (!(texelFetch(u_spacing, ivec2(gl_FragCoord.xy), 0).r > 0.0)) discard;
    o_mask = 1.0;
}
#else
uniform sampler2D u_prev_mask;
uniform sampler2D u_prev_spacing;
uniform sampler2D u_history;    // HISTORY's output of this frame (u_boxes left to this light)
uniform float u_spacing_ratio;
uniform int u_still;            // 1: the same camera: the same pixel's value stands, edge or not
uniform int u_refresh;          // one 4x2 block in u_refresh traces again each moving frame
uniform int u_phase;            // which one (the frame's)
layout(location = 0) out float o_mask;
layout(location = 1) out float o_spacing;

void main()
{
    ivec2 px = ivec2(gl_FragCoord.xy);
    vec3 p, n, ns, to_light;
    float depth;
    float value = shadow_ray_prelude(px, p, n, ns, depth, to_light);
    // (a rotating share of the 4x2 blocks traces again: a value a move let through wrongly,
    // as a shadow thinner than the old samples' spacing, lasts about u_refresh frames)
    bool refresh = u_still == 0 && u_refresh > 1 && ((px.x >> 2) + 3 * (px.y >> 1) + u_phase) % u_refresh == 0;
    float fp = hs_footprint(texelFetch(u_gb_depth, px, 0).r);
    ivec2 q = ivec2(-1);
    if (value < 0.0 && !refresh) {
        q = ivec2(texelFetch(u_history, px, 0).rg);
        for (int i = 0; i < u_boxes && q.x >= 0; ++i)
            if (hs_segment_meets(p, i)) q = ivec2(-1);
    }
    bool reused = false;
    if (q.x >= 0) {
        float c = texelFetch(u_prev_mask, q, 0).r;
        float spacing = 0.0;
        bool flat_ = (c == 0.0 || c == 1.0) && u_still == 0;
        if (u_still == 1 && q == px) { flat_ = true; spacing = abs(texelFetch(u_prev_spacing, q, 0).r); }
        for (int k = 0; k < 9 && flat_ && u_still == 0; ++k) {
            ivec2 r = q + ivec2(k % 3 - 1, k / 3 - 1);
            flat_ = texelFetch(u_prev_mask, r, 0).r == c;
            spacing = max(spacing, abs(texelFetch(u_prev_spacing, r, 0).r));
        }
        if (flat_ && spacing <= u_spacing_ratio * fp) {
            reused = true;
            value = c;
            o_spacing = spacing;
        }
    }
    if (!reused) o_spacing = -max(fp, 1e-30);
    o_mask = value < 0.0 ? 1.0 : value;
    gl_FragDepth = value < 0.0 ? 0.0 : 1.0;
}
#endif
#endif
#endif
