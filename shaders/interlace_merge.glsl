// Interlacing, per light: the full-resolution mask of this frame from its dense trace and the
// history. The trace (raytrace.glsl with HS_INTERLACE) traced one pixel of each 2x2 block, the
// one of phase u_phase (pixel 2q + its offset (u_phase & 1, u_phase >> 1) for texel q), at a
// quarter of the resolution: a
// software rasteriser runs 8 pixels in lock-step, so a full-resolution pass whose other three
// pixels of each block only copied their history cost what a full trace costs.
// Output: the traced value at this phase's pixels; elsewhere the history where its phase is up
// to date (bit phase of u_valid_phases), else -1 (refine_classify.glsl refines those).

#ifdef VERTEX_SHADER
#include "common/fullscreen.glsl"
#endif

#ifdef FRAGMENT_SHADER
uniform sampler2D u_traced;     // this frame's trace: texel q = pixel 2q + the phase's offset
uniform sampler2D u_history;
uniform int u_phase;            // 0..3
uniform int u_valid_phases;
out float o_mask;

void main()
{
    ivec2 mt = ivec2(gl_FragCoord.xy);
    int phase = (mt.x & 1) | ((mt.y & 1) << 1);
    if (phase == u_phase)   // (every such pixel is some texel's: the trace covers ceil((size - offset) / 2))
        o_mask = texelFetch(u_traced, (mt - ivec2(u_phase & 1, u_phase >> 1)) >> 1, 0).r;
    else
        o_mask = ((u_valid_phases >> phase) & 1) != 0 ? texelFetch(u_history, mt, 0).r : -1.0;
}
#endif
