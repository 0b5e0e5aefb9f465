// The ray queue of the pixels a refinement or a reuse marked (passes/refine.py: depth 0 in its
// depth buffer, a ray; 1, done): compute, one invocation per pixel, common/ray_queue.glsl.
// raytrace.glsl's tracing kernel then traces them, as the fragment stage does under the depth
// test.

#ifdef COMPUTE_SHADER
#define HS_QUEUE_GEN
#include "common/ray_queue.glsl"

uniform sampler2D u_marks;      // the refinement's depth buffer (no comparison)

void main()
{
    ivec2 t = ivec2(gl_GlobalInvocationID.xy);
    if (all(lessThan(t, textureSize(u_marks, 0))) && texelFetch(u_marks, t, 0).r < 0.5) hs_enqueue();
    hs_queue_append(t);
}
#endif
