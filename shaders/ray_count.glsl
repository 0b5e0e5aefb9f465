// Counts the pixels with geometry (an occlusion query around this draw): every texel whose
// source pixel has geometry passes, the others are discarded. Writes nothing of use.

#ifdef VERTEX_SHADER
#include "common/fullscreen.glsl"
#endif

#ifdef FRAGMENT_SHADER
#include "common/gbuffer.glsl"

uniform int u_scale;
uniform ivec2 u_offset;         // the source pixel of texel q: q * u_scale + u_offset (clamped)
uniform ivec2 u_full_size;
out float o_mask;

void main()
{
    ivec2 px = min(ivec2(gl_FragCoord.xy) * u_scale + u_offset, u_full_size - 1);
    if (texelFetch(u_gb_position, px, 0).w == 0.0) discard;
    o_mask = 1.0;
}
#endif
