// Soft shadows in the viewport: the running sums of a light's rays over still frames
// (ACCUMULATE: each frame's (weighted visibility, weight) sums, raytrace.glsl HS_SOFT_ACCUM,
// added up), the mask they make (RESOLVE: their ratio, as a final render's pixel divides its
// sums), and a penumbra-only, edge-aware filter of a mask (DENOISE, also for final renders).
// Each frame traces a few samples per pixel, continuing every pixel's sample sequence
// (u_sample_base), so the sums converge to those of the exact share of the light (summing,
// not averaging each frame's share: a frame whose few rays carry little weight, as at a soft
// spot cone's edge, counts for as little); anything that changes resets them
// (RaytracePass.reset_history), so no old frame survives a change.
//
// DENOISE: pixels whose neighbourhood (2 pixels: u_mask_range, soft_range.glsl) holds one value
// only, 0 or 1, lie in an umbra or in the light and keep it: hard edges stay hard. The others
// (penumbrae) average the neighbours within u_radius pixels that lie on the same surface
// (tangent-plane distance against the view depth, normal agreement) and whose value is within
// the noise of its own. The noise of a pixel's share of the light falls as samples^-0.75 (its
// samples are stratified over the light, where independent ones would give samples^-0.5), so
// the range kernel's variance is K v (1 - v) / samples^1.5. Near a penumbra's border (a 0 or 1
// within 2 pixels, where the share bends fastest) K is small, so a narrow penumbra keeps its
// shape; inside a wide penumbra (every share within 2 pixels partial, the share changes slowly)
// K is large and the filter averages its neighbours almost freely. u_radius shrinks as the
// samples add up (the filter's blur fades while the noise it hides does).
#include "common/camera.glsl"
#include "common/gbuffer.glsl"

#ifdef VERTEX_SHADER
#include "common/fullscreen.glsl"
#endif

#ifdef FRAGMENT_SHADER
#define HS_RANGE_K_BORDER 8.0   // DENOISE's K near a penumbra's border and inside one (see above;
#define HS_RANGE_K_INSIDE 30.0  // measured against Cycles, BENCHMARKS.md "Soft shadows")

// The penumbra filter (DENOISE, and NOISE's filter of the two halves): the range kernel's
// variance for share c of a mask of `samples` (inside a penumbra or near its border), and the
// weight of a neighbour at position qp with normal qn, r2 pixels squared away relative to the
// radius + 1, whose share differs from c by d, for the pixel at p (normal n, view depth depth).
float hs_range_sigma2(float c, bool inside, float samples)
{
    return (inside ? HS_RANGE_K_INSIDE : HS_RANGE_K_BORDER) * max(c * (1.0 - c), 0.05)
         / pow(max(samples, 1.0), 1.5);
}

float hs_filter_weight(vec3 p, vec3 n, float depth, vec3 qp, vec3 qn, float r2, float d, float sigma2,
                       float plane_sigma)
{
    float plane = abs(dot(qp - p, n)) / (plane_sigma * depth);
    float nd = max(dot(qn, n), 0.0);
    return exp(-plane * plane - 2.0 * r2 - 0.5 * d * d / sigma2) * pow(nd, 8.0);
}
#ifdef NOISE
// A final render's noise check, per 8 x 8 block of pixels, on every other pixel of each row and
// column (soft.py adds the blocks up): the sum of |a - b|, a and b the shares of the first and
// of the second half of the samples (u_sums: RG all, BA the first half's, raytrace.glsl u_split),
// each filtered here as DENOISE filters a mask of u_samples (half the samples) at radius 1 (its
// "umbra or lit" test over 3 x 3 pixels instead of 5 x 5), and the count of covered pixels.
layout(location = 0) out vec2 o_noise;
uniform sampler2D u_sums;
uniform float u_samples;
uniform float u_plane_sigma;

vec2 hs_halves(ivec2 q) {   // (first half's share, second half's); a half with no weight: the share
    vec4 s = texelFetch(u_sums, q, 0);
    float all_ = s.y > 0.0 ? s.x / s.y : 0.0;
    vec2 late = s.xy - s.zw;
    return vec2(s.w > 0.0 ? s.z / s.w : all_, late.y > 0.0 ? late.x / late.y : all_);
}

void main() {
    ivec2 b0 = ivec2(gl_FragCoord.xy) * 8;
    ivec2 lim = textureSize(u_sums, 0) - 1;
    vec2 acc = vec2(0.0);
    for (int y = 0; y < 8; y += 2)
        for (int x = 0; x < 8; x += 2) {
            ivec2 px = b0 + ivec2(x, y);
            if (px.x > lim.x || px.y > lim.y) continue;
            vec4 pos = texelFetch(u_gb_position, px, 0);
            if (pos.w == 0.0) continue;
            acc.y += 1.0;
            vec2 c = hs_halves(px);
            vec3 n = texelFetch(u_gb_normal, px, 0).xyz;
            float depth = max(texelFetch(u_gb_depth, px, 0).r, 1e-6);
            vec2 lo = c, hi = c;
            vec2 v[9];
            vec3 qps[9], qns[9];
            bool in_reach[9];
            for (int k = 0; k < 9; ++k) {
                ivec2 q = px + ivec2(k % 3 - 1, k / 3 - 1);
                in_reach[k] = false;
                if (any(lessThan(q, ivec2(0))) || any(greaterThan(q, lim))) continue;
                vec4 qp = texelFetch(u_gb_position, q, 0);
                if (qp.w == 0.0) continue;
                in_reach[k] = true;
                v[k] = hs_halves(q);
                qps[k] = qp.xyz;
                qns[k] = texelFetch(u_gb_normal, q, 0).xyz;
                lo = min(lo, v[k]);
                hi = max(hi, v[k]);
            }
            vec2 f;
            for (int h = 0; h < 2; ++h) {
                float ch = c[h];
                if ((ch == 0.0 || ch == 1.0) && lo[h] == ch && hi[h] == ch) { f[h] = ch; continue; }
                float sigma2 = hs_range_sigma2(ch, lo[h] > 0.0 && hi[h] < 1.0, u_samples);
                float s = 0.0, w = 0.0;
                for (int k = 0; k < 9; ++k) {
                    if (!in_reach[k]) continue;
                    float r2 = float((k % 3 - 1) * (k % 3 - 1) + (k / 3 - 1) * (k / 3 - 1)) / 4.0;
                    float wk = hs_filter_weight(pos.xyz, n, depth, qps[k], qns[k], r2, v[k][h] - ch, sigma2,
                                                u_plane_sigma);
                    if (wk <= 1e-4) continue;
                    s += wk * v[k][h];
                    w += wk;
                }
                f[h] = w > 0.0 ? s / w : ch;
            }
            acc.x += abs(f.x - f.y);
        }
    o_noise = acc;
}
#elif defined(ACCUMULATE)
layout(location = 0) out vec2 o_sums;
uniform sampler2D u_new;        // this frame's sums
uniform sampler2D u_acc;        // the sums of the u_count frames before
uniform float u_count;

void main() {
    ivec2 px = ivec2(gl_FragCoord.xy);
    vec2 v = texelFetch(u_new, px, 0).rg;
    o_sums = u_count > 0.0 ? texelFetch(u_acc, px, 0).rg + v : v;
}
#else
layout(location = 0) out float o_mask;
#endif

#ifdef RESOLVE
uniform sampler2D u_sums;

void main() {
    vec2 s = texelFetch(u_sums, ivec2(gl_FragCoord.xy), 0).rg;
    o_mask = s.y > 0.0 ? s.x / s.y : 0.0;
}
#endif

#ifdef PARTIAL
// The marks of the second half of a refinement traced ray by ray in several draws (the early
// stop of raytrace.glsl's single draw, between draws): pixels whose sums so far (probes and
// the first half) give a share strictly between 0 and 1 go on (gl_FragDepth 0); the others,
// all of whose samples saw all or none of the light alike, keep their share (1). Marks only.
uniform sampler2D u_sums;

void main() {
    vec2 s = texelFetch(u_sums, ivec2(gl_FragCoord.xy), 0).rg;
    o_mask = 0.0;
    gl_FragDepth = (s.y > 0.0 && s.x > 0.0 && s.x < s.y) ? 0.0 : 1.0;
}
#endif

#ifdef DENOISE
uniform sampler2D u_mask;
uniform sampler2D u_mask_range; // u_mask's (min, max) over the covered texels within 2 (soft_range.glsl)
uniform int u_radius;
uniform float u_plane_sigma;    // tangent-plane distance, relative to the view depth
uniform float u_samples;        // samples per pixel of u_mask (the range kernel's width follows
                                // the estimate's noise, so real detail such as a textured cut's
                                // shadow stays and noise averages out)


void main() {
    ivec2 px = ivec2(gl_FragCoord.xy);
    ivec2 lim = textureSize(u_mask, 0) - 1;
    float c = texelFetch(u_mask, px, 0).r;
    vec4 pos = texelFetch(u_gb_position, px, 0);
    vec2 near = texelFetch(u_mask_range, px, 0).rg;
    bool umbra_or_lit = (c == 0.0 || c == 1.0) && near.x == c && near.y == c;
    if (pos.w == 0.0 || u_radius <= 0 || umbra_or_lit) { o_mask = c; return; }
    vec3 p = pos.xyz;
    vec3 n = texelFetch(u_gb_normal, px, 0).xyz;
    float depth = max(texelFetch(u_gb_depth, px, 0).r, 1e-6);
    float sum = 0.0, wsum = 0.0;
    float sigma2 = hs_range_sigma2(c, near.x > 0.0 && near.y < 1.0, u_samples);
    for (int dy = -u_radius; dy <= u_radius; ++dy)
        for (int dx = -u_radius; dx <= u_radius; ++dx) {
            ivec2 q = px + ivec2(dx, dy);
            if (any(lessThan(q, ivec2(0))) || any(greaterThan(q, lim))) continue;
            vec4 qp = texelFetch(u_gb_position, q, 0);
            if (qp.w == 0.0) continue;
            float r2 = float(dx * dx + dy * dy) / float((u_radius + 1) * (u_radius + 1));
            float v = texelFetch(u_mask, q, 0).r;
            float w = hs_filter_weight(p, n, depth, qp.xyz, texelFetch(u_gb_normal, q, 0).xyz, r2, v - c, sigma2,
                                       u_plane_sigma);
            if (w <= 1e-4) continue;
            sum += w * v;
            wsum += w;
        }
    o_mask = wsum > 0.0 ? sum / wsum : c;
}
#endif
#endif
