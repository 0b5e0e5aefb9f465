// Pass 2, ray traced: one shadow ray per mask texel towards one light, through the baked scene.
//
// Output (R32F): 1 = lit, 0 = shadowed (between: the light kept through alpha-cut casters). Background texels are 1 (the lighting pass skips them).
// Texels whose surface faces away from the light, or that the light cannot reach (outside a
// spot's cone, behind an area light) are 0 without a ray: unlit anyway.
// The probe pass and HS_SOFT_ACCUM write RG32F sums (weighted visibility, weight) instead of the
// mask, (value, 1) where the answer is known without a ray: the refinement continues each
// pixel's sequence after them; a pixel none of whose rays had a weight writes its highest
// point's answer with a weight of HS_ACCUM_TOP_WEIGHT, which decides only where no frame saw any
// weight, as a final render's highest point does.
//
// Defines (besides the bake's, scene_data.glsl; set in hybrid_shadow_addon/core/gpu/passes/):
// | define           | meaning                                                          | set by            |
// |------------------|------------------------------------------------------------------|-------------------|
// | HS_LIGHT_SUN     | a sun: u_light_vec is the direction towards it                   | trace.py          |
// | HS_LIGHT_LOCAL   | point, spot, area: u_light_vec is its position (bake space)      | trace.py          |
// | HS_MAX_DISTANCE  | shadows only within u_max_distance of the camera, rays no longer | trace.py          |
// | HS_INTERLACE     | quarter-resolution pass: texel q traces pixel 2q + u_offset of   | trace.py, for     |
// |                  | its 2x2 block (this frame's phase; interlace_merge.glsl merges)  | hard.py's plan    |
// | HS_CONSERVATIVE  | a conservative occupancy map decides or shortens the ray         | raytrace.py       |
// |                  | (common/conservative_lookup.glsl)                                | (conservative.py) |
// | HS_LIGHT_GRID    | a hard light's rays look up its light-space grid                 | hard.py, from     |
// | (+ HS_LG_*)      | (common/scene_lightgrid.glsl) instead of walking the BVH         | light_grid.py     |
// | HS_NO_RAYS       | the prelude's answers alone: a light that reaches no pixel       | raytrace.py       |
// |                  | (light_cull.py)                                                  |                   |
// | HS_TERMINATOR    | smooth-shaded models: origins near their shadow terminator rise  | trace.py          |
// |                  | as Cycles' (common/shadow_ray.glsl, shadow_ray_origin)           |                   |
// | HS_SOFT          | an extended light: u_samples rays towards points on it           | trace.py          |
// | HS_SOFT_SHAPE    | its shape (common/soft_light.glsl); the mask is the weighted     | trace.py          |
// |                  | share of the light the pixel sees                                |                   |
// | HS_PACKET_PLANES | packets bounded by the pyramid over the light too                | trace.py          |
// | HS_SOFT_PROBE    | trace HS_PROBES of the samples, write sums                       | soft.py           |
// | HS_SOFT_REFINE   | the rest of the samples, under the depth test, only on the       | soft.py           |
// |                  | pixels soft_range.glsl's CLASSIFY marked                         |                   |
// | HS_SOFT_ACCUM    | write the sums of u_samples rays from u_sample_base (the         | soft.py           |
// |                  | viewport's running sums, chunked draws; soft_accumulate.glsl)    |                   |
// | HS_SOFT_PACKET   | a pixel's samples walk the scene together                        | soft.py           |
// |                  | (common/scene_packet.glsl)                                       |                   |
// | HS_SOFT_FULL     | a refined pixel never stops early                                | soft.py           |
// | HS_LINKING       | light and shadow linking: rays skip the instances outside the    | trace.py (from    |
// |                  | light's blocker set, pixels outside its receiver set are 0       | gpu/linking.py)   |
// | HS_CODE_OUT      | a second output, the pixel's code for the next frame's reuse     | hard.py, with     |
// |                  | (reproject.glsl MARK): +-(3 + footprint), 0.5 between 0 and 1    | reproject.py      |
// | HS_LOOP_CHECK    | tests: a pixel whose loop hit llvmpipe's budget reads            | soft.py           |
// |                  | HS_LOOP_SPENT (RaytraceOptions.loop_check; see below)            |                   |
// | HS_LOOP_DROP     | a soft ray (packet) walked after llvmpipe's loop budget was      | soft.py           |
// |                  | spent is dropped (RaytraceOptions.loop_guard; hs_budget_left)    |                   |
// | HS_QUEUE_GEN     | compute: one invocation per mask texel writes the answers known  | queue.py          |
// |                  | without a ray and appends the other texels to the ray queue      |                   |
// | HS_QUEUE_TRACE   | compute: one invocation per queued texel traces its ray          | queue.py          |
// | HS_QUEUE_LANES   | compute, soft sums: a queued texel's samples spread over this    | soft.py           |
// |                  | many invocations, their sums added up in lane order              |                   |
// | HS_SUMS_ADD      | compute, soft sums: added to the sums image's (the blend's add)  | soft.py           |
//
// Two stages trace: the fragment stage (GL 4.1: a full-screen draw, one texel per fragment, the
// refinement's marks through the depth test) and the compute stage (GL 4.3: the same code over
// the compact ray queue of common/ray_queue.glsl, results stored into image units 0 and 1; the
// soft sums into an RGBA32F image on unit 0).

#ifdef VERTEX_SHADER
#include "common/fullscreen.glsl"
#endif

#if defined(FRAGMENT_SHADER) || defined(COMPUTE_SHADER)
#include "common/camera.glsl"
#include "common/gbuffer.glsl"
#include "common/scene_data.glsl"
#include "common/shadow_ray.glsl"
#ifdef HS_LIGHT_GRID
#include "common/scene_lightgrid.glsl"
#endif
#ifdef HS_CONSERVATIVE
#include "common/conservative_lookup.glsl"
#endif
#ifdef HS_SOFT
#include "common/soft_light.glsl"
#ifdef HS_SOFT_REFINE
uniform sampler2D u_probe;      // the probe pass's sums (full resolution; see hs_probe_value)
#endif
#endif

uniform int u_scale;            // mask texel = u_scale x u_scale full-resolution pixels
#ifdef HS_LINKING
uniform int u_link_receiver;    // the light's light set (common/linking.glsl), -1: it lights all
#endif
uniform ivec2 u_full_size;      // G-buffer size
#ifdef HS_INTERLACE
uniform ivec2 u_offset;         // texel q traces pixel 2q + u_offset (this frame's phase)
#endif

#ifdef COMPUTE_SHADER
#include "common/ray_queue.glsl"
#endif

#define HS_LOOP_SPENT -7.0
#if defined(HS_LOOP_DROP) && defined(HS_SOFT)
// Whether llvmpipe's loop budget is left (every loop of an invocation ends after its first pass
// once all of them together have run 65535 iterations): a loop that wants two passes makes both.
// (Its end is a float test and its bound a uniform: the compiler cannot count its passes, so it
// stays a loop.) A ray or packet walked after the budget was spent ended its walk as if nothing
// were in the way: the soft loops drop it and stop, the pixel's share comes from the rays it
// traced in full.
bool hs_budget_left()
{
    int q = 0;
    for (int z = 0; z <= u_samples; ++z) {
        ++q;
        if (float(q) > 1.5) break;
    }
    return q >= 2;
}
#endif
#if defined(HS_SOFT_PROBE) || defined(HS_SOFT_ACCUM)
#define HS_SOFT_SUMS
#define HS_ACCUM_TOP_WEIGHT 1.0e-30
#ifndef COMPUTE_SHADER
out vec4 o_sums;                // (weighted visibility, weight) of this pass's rays, and the same
                                // of those among them before sample u_split (the first half of
                                // a final render's samples, for its noise check: soft.py)
#endif
uniform int u_split;
float o_mask;                   // the answers known without a ray: written as (o_mask, 1)
vec2 hs_sums = vec2(-1.0);
vec2 hs_first = vec2(0.0);
#elif defined(COMPUTE_SHADER)
#if defined(HS_CODE_OUT) && (defined(HS_INTERLACE) || defined(HS_SOFT))
#error HS_CODE_OUT is for a hard light's full-resolution mask
#endif
float o_mask;                   // stored into image unit 0 (and the code into unit 1)
#ifdef HS_CODE_OUT
float o_code;
#endif
#elif defined(HS_CODE_OUT)
#if defined(HS_INTERLACE) || defined(HS_SOFT)
#error HS_CODE_OUT is for a hard light's full-resolution mask
#endif
layout(location = 0) out float o_mask;
layout(location = 1) out float o_code;
#else
out float o_mask;
#endif

#ifdef HS_QUEUE_LANES
#if !defined(HS_QUEUE_TRACE) || !defined(HS_SOFT_ACCUM) || defined(HS_SOFT_PROBE) || defined(HS_SOFT_REFINE) || defined(HS_SOFT_PACKET)
#error HS_QUEUE_LANES spreads the tracing kernel's soft sums' ray-by-ray loop (HS_SOFT_ACCUM) over lanes
#endif
#define HS_LANE_STEP HS_QUEUE_LANES
int hs_lane = 0;                // this invocation's lane among its texel's
vec3 hs_top_o, hs_top_d;        // the light's highest point from the ray's origin (hs_light_top)
float hs_top_tmax, hs_top_w;
#else
#define HS_LANE_STEP 1
const int hs_lane = 0;
#endif

#ifdef HS_SOFT
// The visibility of a soft light's highest point (hs_light_top: direction d, the light at tmax)
// from o, which decides a pixel none of whose samples had a weight.
float hs_top_visibility(vec3 o, vec3 d, float tmax)
{
#ifdef HS_MAX_DISTANCE
    tmax = min(tmax, u_max_distance / length(d));
#endif
    return hs_visibility(o, d, tmax);
}
#endif

// The answer of mask texel mt into o_mask (HS_QUEUE_GEN: the answer known without a ray, or
// the texel appended to the ray queue and nothing written).
void trace_main(ivec2 mt)
{
#ifdef HS_INTERLACE
    ivec2 px = min(mt * 2 + u_offset, u_full_size - 1);
#else
    ivec2 px = mask_source_pixel(mt, u_scale, u_full_size);
#endif
    vec3 p, n, ns, to_light;
    float depth;
    float known = shadow_ray_prelude(px, p, n, ns, depth, to_light);
#ifdef HS_LINKING
    // a surface the light does not light (its receiver collection leaves it out): 0, no ray
    if (u_link_receiver >= 0 && texelFetch(u_gb_position, px, 0).w > 0.5
        && !hs_link_receives(int(texelFetch(u_gb_material, px, 0).z + 0.5), u_link_receiver)) known = 0.0;
#endif
#ifdef HS_NO_RAYS
    // a light no pixel needs a ray of (passes/light_cull.py): the answers without one, no walk
    o_mask = max(known, 0.0);
    return;
#endif
    if (known >= 0.0) { o_mask = known; return; }
#ifdef HS_QUEUE_GEN
    hs_enqueue();
    return;
#endif

    vec3 o = shadow_ray_origin(px, p, n, ns, depth, to_light);
#ifdef HS_SOFT
    // the light's highest point above o's horizon: when even it is below, the whole light is
    // (unlit, no ray, known); it also decides a pixel none of whose samples has a weight
    vec3 top_d;
    float top_tmax, top_w;
    hs_light_top(o, ns, top_d, top_tmax, top_w);
    if (top_w == 0.0 && !(dot(ns, top_d) > 0.0)) { o_mask = 0.0; return; }
    // an extended light: the weighted share of u_samples points on it that o sees
#ifdef HS_SOFT_PROBE
    int n_samples = min(u_samples, HS_PROBES);
#else
    int n_samples = u_samples;
#ifdef HS_SOFT_REFINE
    // (the pixels outside any penumbra, where every probe nearby saw all or none of the light
    // alike, kept their probe answer: soft_range.glsl's CLASSIFY wrote it, and the depth test
    // keeps this pass off them)
    vec2 ps = texelFetch(u_probe, px, 0).rg;
    float pv = hs_probe_value(ps);
#endif
#endif
    float sw = 0.0, sv = 0.0;
    int k0 = 0;
#ifdef HS_SOFT_REFINE
    // the probes were this pixel's first HS_PROBES samples (the same sequence, in the same
    // order): continue after them with their sums, exactly as if traced again (below 10
    // samples the early stop's check falls among the probes: those are traced again)
#if defined(HS_SOFT_ACCUM) || defined(HS_SOFT_FULL)
    { sv = ps.x; sw = ps.y; k0 = HS_PROBES; }   // (a viewport frame, packets: all its samples, no early stop)
#else
    if ((n_samples >> 1) > HS_PROBES) { sv = ps.x; sw = ps.y; k0 = HS_PROBES; }
#endif
#endif
#ifdef HS_SOFT_PACKET
    // the samples in packets of up to HS_PACKET rays, each packet one walk of the scene
    // (common/scene_packet.glsl; with HS_SOFT_FULL: a refined pixel traces all its samples, one
    // walk costs less than two halves with a stop between)
    float pw[HS_PACKET];
    uvec2 seeds = hs_sample_seeds(px);
#ifdef HS_PACKET_PLANES
    hs_pk_set_pyramid(o, u_light_vec, u_light_u, u_light_v);
#endif
    for (int k = k0; k < n_samples; ) {
        // a packet's rays in the order of the band across the light they aim at (eight bands),
        // so that a caster's edge that blocks the rays of one side leaves a narrower span of
        // rays to test against the next triangles (scene_packet.glsl). A packet stays within one
        // aligned block of 64 samples of the sequence; within the smallest aligned block of
        // P >= 8 samples that holds it each band has at most P / 8 of them (every dimension of
        // the scrambled Sobol sequence is a (0,1)-sequence), so ray slot cap * band + i is the
        // i-th ray of that band, and the slots a packet leaves empty are not live.
        int s0 = u_sample_base + k;
        int kend = min(n_samples, min(k + HS_PACKET, k + 64 - (s0 & 63)));
        int cnt = kend - k;
        int span = s0 ^ (s0 + cnt - 1);
        int slots = span == 0 ? 8 : max(8, 2 << findMSB(span));
        int cap = slots >> 3;
        int fill[8];
        for (int g = 0; g < 8; ++g) fill[g] = 0;
        uvec2 live = uvec2(0u);
#ifdef HS_SOFT_SUMS
        uvec2 early = uvec2(0u);        // the slots of samples before u_split
#endif
        for (int j = 0; j < cnt; ++j) {
            vec2 xi = hs_sample2s(seeds, s0 + j);
#if HS_SOFT_SHAPE == 1
            int g = min(int(xi.y * 8.0), 7);   // (a sphere light: eighths of a turn)
#else
            int g = min(int(xi.x * 8.0), 7);
#endif
            int q = cap * g + fill[g];
            fill[g] += 1;
            vec3 sd;
            float stm, w;
            hs_light_sample(o, ns, xi, sd, stm, w);
#ifdef HS_MAX_DISTANCE
            stm = min(stm, u_max_distance / length(sd));
#endif
            hs_pk_d[q] = sd;
            hs_pk_t[q] = stm;
            pw[q] = w;
            if (w > 0.0) live |= hs_bit(q);
#ifdef HS_SOFT_SUMS
            if (s0 + j < u_split) early |= hs_bit(q);
#endif
        }
        uvec2 occ = hs_trace_packet(o, slots, live);
#ifdef HS_LOOP_DROP
        if (!hs_budget_left()) break;
#endif
        for (int j = 0; j < slots; ++j) {
            if (hs_has(live, j)) {
#ifdef HS_HAS_ALPHA
                float v = hs_has(occ, j) ? 0.0 : pw[j] * hs_pk_vis[j];
#else
                float v = hs_has(occ, j) ? 0.0 : pw[j];
#endif
                sw += pw[j];
                sv += v;
#ifdef HS_SOFT_SUMS
                if (hs_has(early, j)) hs_first += vec2(v, pw[j]);
#endif
            }
        }
        k = kend;
    }
#else
    // (HS_QUEUE_LANES: this invocation takes every HS_QUEUE_LANES-th sample from its lane's;
    // the tracing kernel's main adds the lanes' sums up)
    for (int k = k0 + hs_lane; k < n_samples; k += HS_LANE_STEP) {
        vec3 sd;
        float stm, w;
        hs_light_sample(o, ns, hs_sample2(px, u_sample_base + k), sd, stm, w);
#ifdef HS_MAX_DISTANCE
        stm = min(stm, u_max_distance / length(sd));
#endif
        if (w > 0.0) {
            float v = w * hs_visibility(o, sd, stm);
#ifdef HS_LOOP_DROP
            if (!hs_budget_left()) break;
#endif
            sv += v;
            sw += w;
#ifdef HS_SOFT_SUMS
            if (u_sample_base + k < u_split) hs_first += vec2(v, w);
#endif
        }
#if defined(HS_SOFT_REFINE) && !defined(HS_SOFT_ACCUM) && !defined(HS_SOFT_FULL)
        // a pixel refined only for a neighbour's sake (a penumbra's fringe): when the first
        // half of its samples, spread over the light, all agree with its own probes, it keeps
        // that answer (its share is then within a few % of it)
        if (k == (n_samples >> 1) - 1 && sw > 0.0 && ((pv == 0.0 && sv == 0.0) || (pv == 1.0 && sv == sw))) break;
#endif
    }
#endif
#ifdef HS_QUEUE_LANES
    hs_top_o = o; hs_top_d = top_d; hs_top_tmax = top_tmax; hs_top_w = top_w;   // (main's, once the lanes are summed)
#elif !defined(HS_SOFT_PROBE)
    if (sw == 0.0 && top_w > 0.0) {   // no sample reached above the horizon: the highest point decides
#ifdef HS_SOFT_ACCUM
        sw = HS_ACCUM_TOP_WEIGHT;
#else
        sw = 1.0;
#endif
        sv = sw * hs_top_visibility(o, top_d, top_tmax);
    }
#endif
#ifdef HS_SOFT_SUMS
    hs_sums = vec2(sv, sw);   // (probes, sw 0: no probe had any weight, a spread's edge: not known)
#else
    o_mask = sw > 0.0 ? sv / sw : 0.0;
#endif
#ifdef HS_LOOP_CHECK
    // llvmpipe stops every loop of an invocation once all its loops together have run 65535
    // iterations: a loop over u_samples that ends early here says this pixel's rays were cut
    // short (a test's check: the answer becomes HS_LOOP_SPENT)
    {
        int q = 0;
        for (int z = 0; z < u_samples; ++z) ++q;
#ifdef HS_SOFT_SUMS
        if (q != u_samples) hs_sums = vec2(HS_LOOP_SPENT, 1.0);
#else
        if (q != u_samples) o_mask = HS_LOOP_SPENT;
#endif
    }
#endif
    return;
#endif
#ifdef HS_LIGHT_LOCAL
    vec3 d = u_light_vec - o;     // the light is at t = 1
    float tmax = 1.0;
#else
    vec3 d = u_light_vec;
    float tmax = HS_FLT_BIG;
#endif
#ifdef HS_MAX_DISTANCE
    tmax = min(tmax, u_max_distance / length(d));
#endif
#ifdef HS_CONSERVATIVE
    // The ray stays in o's column of the map; casters there lie at depth >= D, so a hit needs
    // the ray's depth >= D: cut tmax there, or skip the ray when o is nearer the light than D.
    {
        float D, vz;
        if (cm_lookup(o, D, vz)) {
            if (D >= vz) { o_mask = 1.0; return; }
#ifdef HS_LIGHT_LOCAL
            tmax = min(tmax, 1.0 - D / vz);
#else
            tmax = min(tmax, (vz - D) / -dot(d, u_cm_basis[0][2]));
#endif
        }
    }
#endif
#ifdef HS_LIGHT_GRID
    o_mask = hs_lg_visibility(o, d, tmax);     // a hard light: its light-space grid
#else
    o_mask = hs_visibility(o, d, tmax);
#endif
}

// the code of mask texel mt for the next frame's reuse (HS_CODE_OUT)
float trace_code(ivec2 mt)
{
    float s = 3.0 + hs_footprint(texelFetch(u_gb_depth, mt, 0).r);
    return o_mask == 1.0 ? s : (o_mask == 0.0 ? -s : 0.5);
}

#ifdef FRAGMENT_SHADER
void main()
{
    trace_main(ivec2(gl_FragCoord.xy));
#ifdef HS_CODE_OUT
    o_code = trace_code(ivec2(gl_FragCoord.xy));
#endif
#ifdef HS_SOFT_SUMS
    o_sums = hs_sums.y >= 0.0 ? vec4(hs_sums, hs_first) : vec4(o_mask, 1.0, 0.0, 0.0);
#endif
}
#else
#ifdef HS_SOFT_SUMS
layout(rgba32f, binding = 0) uniform image2D u_mask_out;     // the sums (HS_SUMS_ADD: added to)

// sums s into texel mt (HS_SUMS_ADD: added to what is there, as the fragment stage's blend adds)
void store_sums(ivec2 mt, vec4 s)
{
#ifdef HS_SUMS_ADD
    s += imageLoad(u_mask_out, mt);
#endif
    imageStore(u_mask_out, mt, s);
}

void store(ivec2 mt)
{
    store_sums(mt, hs_sums.y >= 0.0 ? vec4(hs_sums, hs_first) : vec4(o_mask, 1.0, 0.0, 0.0));
}
#else
layout(r32f, binding = 0) uniform writeonly image2D u_mask_out;
#ifdef HS_CODE_OUT
layout(r32f, binding = 1) uniform writeonly image2D u_code_out;
#endif

void store(ivec2 mt)
{
    imageStore(u_mask_out, mt, vec4(o_mask));
#ifdef HS_CODE_OUT
    imageStore(u_code_out, mt, vec4(trace_code(mt)));
#endif
}
#endif

#ifdef HS_QUEUE_LANES
// A queued texel's samples spread over HS_QUEUE_LANES neighbouring invocations of a group: each
// traces its lane's share, then the texel's first lane adds the lanes' sums up in lane order (so
// the result does not depend on timing) and stores them.
shared vec4 hs_lane_sums[HS_QUEUE_GROUP];

void main()
{
    ivec2 mt;
    bool live = hs_dequeue(mt);
    uint me = gl_LocalInvocationID.x;
    hs_lane = int(me) % HS_QUEUE_LANES;
    if (live) trace_main(mt);
    hs_lane_sums[me] = live && hs_sums.y >= 0.0 ? vec4(hs_sums, hs_first) : vec4(0.0);
    barrier();
    if (!live || hs_lane != 0) return;
    if (hs_sums.y < 0.0) {      // an answer known without a ray (the same on every lane)
        store_sums(mt, vec4(o_mask, 1.0, 0.0, 0.0));
        return;
    }
    vec4 s = vec4(0.0);
    bool spent = false;
    for (uint l = 0u; l < uint(HS_QUEUE_LANES); ++l) {
        vec4 part = hs_lane_sums[me + l];
        spent = spent || part.x == HS_LOOP_SPENT;
        s += part;
    }
    if (s.y == 0.0 && hs_top_w > 0.0) {   // no sample reached above the horizon: the highest point decides
        s.y = HS_ACCUM_TOP_WEIGHT;
        s.x = s.y * hs_top_visibility(hs_top_o, hs_top_d, hs_top_tmax);
    }
    if (spent) s = vec4(HS_LOOP_SPENT, 1.0, 0.0, 0.0);
    store_sums(mt, s);
}
#else
void main()
{
#ifdef HS_QUEUE_GEN
    ivec2 mt = ivec2(gl_GlobalInvocationID.xy);
    bool inside = all(lessThan(mt, imageSize(u_mask_out)));
    if (inside) trace_main(mt);
    hs_queue_append(mt);
    if (inside && !hs_queued) store(mt);
#else
    ivec2 mt;
    if (!hs_dequeue(mt)) return;
    trace_main(mt);
    store(mt);
#endif
}
#endif
#endif
#endif
