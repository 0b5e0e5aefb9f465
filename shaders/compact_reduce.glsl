// Histogram pyramid, one level up: each texel sums the 2x2 texels below it (common/compact.glsl).

#ifdef VERTEX_SHADER
#include "common/fullscreen.glsl"
#endif

#ifdef FRAGMENT_SHADER
uniform sampler2D u_src;
uniform ivec2 u_src_off;
uniform ivec2 u_src_size;
uniform ivec2 u_dst_off;
out float o_count;

void main()
{
    ivec2 b = (ivec2(gl_FragCoord.xy) - u_dst_off) * 2;
    float s = 0.0;
    for (int k = 0; k < 4; ++k) {
        ivec2 c = b + ivec2(k & 1, k >> 1);
        if (all(lessThan(c, u_src_size))) s += texelFetch(u_src, u_src_off + c, 0).r;
    }
    o_count = s;
}
#endif
