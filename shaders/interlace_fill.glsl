// Interlacing, second step: texels the trace marked -1 (their phase has no up-to-date history
// since the last change) take the value traced this frame in their 2x2 block. Moving views so
// show this frame's rays at half resolution (never stale ones); a still view converges to every
// texel traced in 4 frames.

#ifdef VERTEX_SHADER
#include "common/fullscreen.glsl"
#endif

#ifdef FRAGMENT_SHADER
uniform sampler2D u_traced;
uniform int u_phase;
in vec2 v_uv;
out float o_mask;

void main()
{
    ivec2 mt = ivec2(gl_FragCoord.xy);
    float m = texelFetch(u_traced, mt, 0).r;
    if (m < 0.0) {
        // (the block's ray exists: raytrace.glsl traces blocks cut by the edge in full)
        m = texelFetch(u_traced, (mt & ~1) + ivec2(u_phase & 1, u_phase >> 1), 0).r;
    }
    o_mask = m;
}
#endif
