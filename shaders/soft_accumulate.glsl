// Soft shadows in the viewport: the running mean of a light's masks over still frames
// (ACCUMULATE), and a penumbra-only, edge-aware filter of that mean while it has few samples
// (DENOISE). Each frame's mask traces a few samples per pixel, continuing every pixel's sample
// sequence (u_sample_base), so the mean converges to the exact share of the light; anything
// that changes resets it (RaytracePass.reset_history), so no old frame survives a change.
//
// DENOISE: pixels whose neighbourhood (2 pixels: u_mask_range, soft_range.glsl) holds one value
// only, 0 or 1, lie in an umbra or in the light and keep it: hard edges stay hard. The others (penumbrae) average
// the neighbours within u_radius pixels that lie on the same surface (tangent-plane distance
// against the view depth, normal agreement) and whose value is within the noise of its own;
// u_radius shrinks as the
// samples add up (the filter's blur fades while the noise it hides does).
#include "common/camera.glsl"
#include "common/gbuffer.glsl"

#ifdef VERTEX_SHADER
#include "common/fullscreen.glsl"
#endif

#ifdef FRAGMENT_SHADER
layout(location = 0) out float o_mask;

#ifdef ACCUMULATE
uniform sampler2D u_new;        // this frame's mask
uniform sampler2D u_acc;        // the mean of the u_count frames before
uniform float u_count;

void main() {
    ivec2 px = ivec2(gl_FragCoord.xy);
    float v = texelFetch(u_new, px, 0).r;
    o_mask = u_count > 0.0 ? (texelFetch(u_acc, px, 0).r * u_count + v) / (u_count + 1.0) : v;
}
#endif

#ifdef DENOISE
uniform sampler2D u_mask;
uniform sampler2D u_mask_range; // u_mask's (min, max) over the covered texels within 2 (soft_range.glsl)
uniform int u_radius;
uniform float u_plane_sigma;    // tangent-plane distance, relative to the view depth
uniform float u_samples;        // samples per pixel of u_mask: the range kernel's width is twice
                                // the estimate's noise, sqrt(v (1 - v) / samples), so real
                                // detail (a textured cut's shadow) stays and noise averages out

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
    float sigma2 = 4.0 * max(c * (1.0 - c), 0.05) / max(u_samples, 1.0);
    for (int dy = -u_radius; dy <= u_radius; ++dy)
        for (int dx = -u_radius; dx <= u_radius; ++dx) {
            ivec2 q = px + ivec2(dx, dy);
            if (any(lessThan(q, ivec2(0))) || any(greaterThan(q, lim))) continue;
            vec4 qp = texelFetch(u_gb_position, q, 0);
            if (qp.w == 0.0) continue;
            float plane = abs(dot(qp.xyz - p, n)) / (u_plane_sigma * depth);
            float nd = max(dot(texelFetch(u_gb_normal, q, 0).xyz, n), 0.0);
            float r2 = float(dx * dx + dy * dy) / float((u_radius + 1) * (u_radius + 1));
            float v = texelFetch(u_mask, q, 0).r;
            float w = exp(-plane * plane - 2.0 * r2 - 0.5 * (v - c) * (v - c) / sigma2) * pow(nd, 8.0);
            if (w <= 1e-4) continue;
            sum += w * v;
            wsum += w;
        }
    o_mask = wsum > 0.0 ? sum / wsum : c;
}
#endif
#endif
