// Reuse of shadow visibility across camera moves (passes/reproject.py): each pixel finds its
// surface point in the previous frame's image and keeps what that frame knew there where the
// surface is the same.
//
// STORE: the G-buffer kept for the next frame (o_geo: world xyz, instance index + 1, 0 on
// background; o_nrm: geometric normal, footprint of a pixel on the surface).
// MARK (hard lights, no mode define): per pixel, the answer without a ray (shadow_ray_prelude),
// else the previous mask at HISTORY's point where the previous frame's codes of the 4x4 samples
// around it (HS_GROUP_VOTE, which traces a marked pixel's group too; else 8x8), all on its
// object, all say lit or all say shadowed (no shadow edge) and those samples were no sparser
// than u_spacing_ratio of this frame's pixel footprint (a zoom in retraces, so a shadow thinner
// than the old spacing is found), and (HS_BOXES) the point's shadow segment meets no edited
// box; HS_STILL (the same camera): the same pixel's value, edge or not. Those pixels are
// written (mask, code) and counted (an occlusion query); the others are discarded and keep the
// cleared depth that marks them for the trace, which writes their mask and code (raytrace.glsl
// HS_CODE_OUT). HS_GROUP_VOTE (refine.py's rule group: llvmpipe): every pixel of a SIMD group
// that holds a marked pixel is marked too, unless it is known without a ray (see
// refine_classify.glsl).
// A code (o_code) is +-2 for a mask of 1 or 0 known without a ray (background, facing away:
// true for any sampling), +-(3 + s) for one whose samples were s apart on the surface (this
// frame's footprint where traced, what a reused value stood on), 0.5 for a mask between.
// HISTORY: per pixel, its surface point's position in the previous frame's window (pixels) where
// hs_history_pixel accepts it but for the edited boxes (light-independent: once a frame, for
// every hard light's MARK), -1 where it has none, -2 on background; and its footprint.
// SOFT: the previous frame's accumulated sums (RG: weighted visibility, weight; B: samples) at
// the previous pixel where hs_history_pixel accepts it, else 0 (the pixel starts over).
//
// hs_history_pixel rejects: background, a point behind or outside the previous view, another
// instance there, normals apart (u_normal_cos), a point off the previous sample's surface by more
// than u_pos_tol footprints (6 times that / the view's cosine along it), a grazing view in
// either frame (u_view_cos), a point beyond the previous frame's max distance, and (HS_BOXES) a
// shadow segment (or a soft light's cone, widened by u_pad_abs + u_pad_slope x distance) that
// meets one of the u_boxes edited boxes (bake space).

#ifdef VERTEX_SHADER
#include "common/fullscreen.glsl"
#endif

#ifdef FRAGMENT_SHADER
#ifdef HS_GROUP_VOTE
#extension GL_ARB_shader_group_vote : require
#endif
#include "common/camera.glsl"
#include "common/gbuffer.glsl"
#ifndef STORE
#include "common/shadow_ray.glsl"
#endif

#define HS_MAX_BOXES 32
#ifdef HS_GROUP_VOTE
#define HS_RING 1       // MARK: the samples read around a point, 2 x (HS_RING + 1) a side
#else
#define HS_RING 3
#endif

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
#ifdef HS_BOXES
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

// Whether the segment from p can meet any edited box.
bool hs_segment_meets_any(vec3 p)
{
    for (int i = 0; i < u_boxes; ++i)
        if (hs_segment_meets(p, i)) return true;
    return false;
}
#endif

vec2 hs_win;    // hs_history_pixel's point in the previous frame's window (pixels)

// The previous frame's pixel that holds pixel px's surface point, or (-1, -1) (-2: background).
ivec2 hs_history_pixel(ivec2 px, out float footprint)
{
    footprint = 0.0;
    vec4 pos = texelFetch(u_gb_position, px, 0);
    if (pos.w == 0.0) return ivec2(-2);
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
#ifdef HS_BOXES
    if (hs_segment_meets_any(p_bake)) return ivec2(-1);
#endif
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
layout(location = 0) out vec4 o_win;

void main()
{
    float fp;
    ivec2 q = hs_history_pixel(ivec2(gl_FragCoord.xy), fp);
    o_win = vec4(q.x < 0 ? vec2(q) : hs_win, fp, 0.0);
}
#else
uniform sampler2D u_prev_mask;
uniform sampler2D u_prev_code;
uniform sampler2D u_history;    // HISTORY's output of this frame (the edited boxes left to this light)
uniform float u_spacing_ratio;
uniform int u_refresh;          // one 4x2 block in u_refresh traces again each moving frame
uniform int u_phase;            // which one (the frame's)
layout(location = 0) out float o_mask;
layout(location = 1) out float o_code;

// The previous mask's value at HISTORY's point `win` of pixel px (footprint fp), or -1; `code`:
// the value's code.
float hs_reused_value(ivec2 px, vec2 win, float fp, out float code)
{
    ivec2 q = ivec2(floor(win));
#ifdef HS_STILL
    code = texelFetch(u_prev_code, q, 0).r;
    return q == px ? texelFetch(u_prev_mask, q, 0).r : -1.0;
#else
    // the codes of the samples around the point: gathers of 2x2 at points 1, 3, ... pixels off
    // it diagonally, 4x4 samples (HS_GROUP_VOTE, which traces a marked pixel's group as well)
    // or 8x8. A shadow edge that passes between the point and its samples separates some of
    // them, as the point lies among them; the ring beyond the nearest ones finds the corners
    // and thin ends of shadows that reach between samples from an edge nearby. They must lie
    // on the point's own object (another object's samples say nothing of it).
    vec2 inv = 1.0 / vec2(textureSize(u_prev_code, 0));
    vec4 lo4 = vec4(1e30), hi4 = vec4(-1e30);
    for (int j = -HS_RING; j <= HS_RING; j += 2)
        for (int i = -HS_RING; i <= HS_RING; i += 2) {
            vec4 c = textureGather(u_prev_code, (win + vec2(i, j)) * inv, 0);
            lo4 = min(lo4, c);
            hi4 = max(hi4, c);
        }
    float lo = min(min(lo4.x, lo4.y), min(lo4.z, lo4.w)), hi = max(max(hi4.x, hi4.y), max(hi4.z, hi4.w));
    bool same = u_same_instance == 0
             || all(equal(textureGather(u_prev_geo, win * inv, 3), vec4(texelFetch(u_gb_material, px, 0).z + 1.0)));
    float spacing = max(max(hi, -lo) - 3.0, 0.0);  // the sparsest of their samples' spacings
    code = hi <= -2.0 ? -(3.0 + spacing) : 3.0 + spacing;
    return same && (lo >= 2.0 || hi <= -2.0) && spacing <= u_spacing_ratio * fp ? float(lo >= 2.0) : -1.0;
#endif
}

void main()
{
    ivec2 px = ivec2(gl_FragCoord.xy);
    vec4 h = texelFetch(u_history, px, 0);
    float code = 0.0;
    float value = hs_reused_value(px, h.xy, max(h.z, 1e-30), code);
    if (h.x < 0.0) value = -1.0;
#ifndef HS_STILL
    // (a rotating share of the 4x2 blocks traces again: a value a move let through wrongly,
    // as a shadow thinner than the old samples' spacing, lasts about u_refresh frames)
    if (u_refresh > 1 && ((px.x >> 2) + 3 * (px.y >> 1) + u_phase) % u_refresh == 0) value = -1.0;
#endif
    vec3 p, n, ns, to_light;
    float depth;
    float answer = shadow_ray_prelude(px, p, n, ns, depth, to_light);
#ifdef HS_BOXES
    if (answer < 0.0 && hs_segment_meets_any(p)) value = -1.0;
#endif
    bool known = answer >= 0.0;
    if (known) { value = answer; code = answer == 1.0 ? 2.0 : -2.0; }
#ifdef HS_GROUP_VOTE
    // (the trace pays a group its slowest lane: the group's other pixels get their exact
    // answer for no extra time; uniform control flow: every lane votes)
    if (anyInvocationARB(value < 0.0) && !known) value = -1.0;
#endif
    if (value < 0.0) discard;     // (left to the trace: its depth stays the cleared mark)
    o_mask = value;
    o_code = code;
}
#endif
#endif
#endif
