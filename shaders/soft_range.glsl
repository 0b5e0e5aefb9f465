// The smallest and largest value of a soft mask over the 5x5 texels around each one (the
// probe pass's sums, SUMS and CLASSIFY: 9x9, HS_PROBE_RADIUS; the G-buffer's covered texels
// only; borders clamped), in two 1D passes of 5 (9) texels: FIRST along x
// from the mask (R; with SUMS the probe pass's sums, RG), then along y from FIRST's ranges (RG). Output (min, max); (big, -big)
// where no covered texel is in reach.
//
// raytrace.glsl (HS_SOFT_REFINE) reads the probe mask's ranges: a pixel whose probes and every
// covered probe within HS_PROBE_RADIUS pixels saw all or none of the light alike (min = max =
// its own value, 0 or 1) keeps its probe answer; soft_accumulate.glsl (DENOISE) reads the refined mask's
// ranges the same way to leave umbrae and lit areas alone. Both once looped over the 25 texels
// themselves (50 fetches per pixel on a software rasteriser, where fetches dominate); these
// two passes take 15.
//
// CLASSIFY (the second pass over the probe ranges): instead of the range, decide there and then
// which pixels keep their probe answer (u_probe: the probe pass's sums), as raytrace.glsl's
// HS_SOFT_REFINE would: those get it (the value; ACCUM: the sums) and gl_FragDepth 1, the
// others gl_FragDepth 0, so the refinement draw runs only on them under the depth test
// (raytrace.glsl HS_SOFT_REFINE) and the pixels it leaves cost nothing.
#ifdef VERTEX_SHADER
#include "common/fullscreen.glsl"
#endif

#ifdef FRAGMENT_SHADER
#include "common/gbuffer.glsl"
#if defined(SUMS) || defined(CLASSIFY)
#include "common/soft_probe.glsl"
#endif

#if defined(SUMS) || defined(CLASSIFY)
#define HS_RANGE_RADIUS HS_PROBE_RADIUS   // the probes' (common/soft_probe.glsl)
#else
#define HS_RANGE_RADIUS 2     // a mask's, for soft_accumulate.glsl's DENOISE
#endif
#define HS_RANGE_BIG 3.0e38

uniform sampler2D u_src;
uniform ivec2 u_step;         // (1, 0) or (0, 1)
#ifdef CLASSIFY
uniform sampler2D u_probe;
out vec4 o_answer;            // (with ACCUM: the probe sums, twice: they are also the first of the
                              // first half's samples, raytrace.glsl u_split)
#else
out vec2 o_range;
#endif

void main()
{
    ivec2 px = ivec2(gl_FragCoord.xy);
    ivec2 lim = textureSize(u_src, 0) - 1;
    vec2 r = vec2(HS_RANGE_BIG, -HS_RANGE_BIG);
    for (int k = -HS_RANGE_RADIUS; k <= HS_RANGE_RADIUS; ++k) {
        ivec2 q = clamp(px + k * u_step, ivec2(0), lim);
#ifdef FIRST
        if (texelFetch(u_gb_position, q, 0).w != 0.0) {
#ifdef SUMS
            float v = hs_probe_value(texelFetch(u_src, q, 0).rg);   // the probe pass's sums
#else
            float v = texelFetch(u_src, q, 0).r;
#endif
            r = vec2(min(r.x, v), max(r.y, v));
        }
#else
        vec2 v = texelFetch(u_src, q, 0).rg;
        r = vec2(min(r.x, v.x), max(r.y, v.y));
#endif
    }
#ifdef CLASSIFY
    vec2 ps = texelFetch(u_probe, px, 0).rg;
    float pv = hs_probe_value(ps);
    bool keep = (pv == 0.0 || pv == 1.0) && r.x == pv && r.y == pv;
    if (texelFetch(u_gb_position, px, 0).w == 0.0) {   // background: lit, as the trace writes it
        keep = true;
        pv = 1.0;
        ps = vec2(1.0);
    }
#ifdef ACCUM
    o_answer = vec4(ps, ps);
#else
    o_answer = vec4(pv, 0.0, 0.0, 0.0);
#endif
    gl_FragDepth = keep ? 1.0 : 0.0;
#else
    o_range = r;
#endif
}
#endif
