// Refinement, last step: pixels that needed a ray take it from the compacted trace (their entry
// from common/compact.glsl's pyramid). Drawn under the depth test that refine_classify.glsl set
// up, so it runs only where a ray was needed; the other pixels keep what classify wrote.

#ifdef VERTEX_SHADER
#include "common/fullscreen.glsl"
#endif

#ifdef FRAGMENT_SHADER
#include "common/compact.glsl"

uniform sampler2D u_rays;       // the compacted trace
out float o_mask;

void main()
{
    ivec2 px = ivec2(gl_FragCoord.xy);
    o_mask = texelFetch(u_rays, compact_texel(compact_prefix(px)), 0).r;
}
#endif
