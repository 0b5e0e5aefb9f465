// Refinement, once per frame: which of its 2x2 surrounding coarse samples (common/refine_grid.glsl)
// can stand for a full-resolution pixel, as bits 1, 2, 4, 8 (sample cell + (0,0), (1,0), (0,1),
// (1,1)): the sample lies in the image, on the same instance, with its normal within
// u_normal_cos of the pixel's and within u_plane_tol x view depth x spacing of the pixel's
// tangent plane (so depth and crease edges, thin receivers and silhouettes get their own rays).
// None can where the camera sees the surface at a grazing angle (|cos| below u_view_cos): the
// samples' spacing on the surface is stretched there by 1/|cos| along the view, and a shadow's
// edge or a thin shadow a pixel high (distant terrain, a ground seen low) falls between sample
// rows without any sample seeing it.

#ifdef VERTEX_SHADER
#include "common/fullscreen.glsl"
#endif

#ifdef FRAGMENT_SHADER
#include "common/camera.glsl"
#include "common/gbuffer.glsl"
#include "common/refine_grid.glsl"

uniform float u_plane_tol;
uniform float u_view_cos;
uniform float u_normal_cos;
out float o_bits;

void main()
{
    ivec2 px = ivec2(gl_FragCoord.xy);
    vec4 pos = texelFetch(u_gb_position, px, 0);
    if (pos.w == 0.0) { o_bits = 0.0; return; }
    vec3 n = texelFetch(u_gb_normal, px, 0).xyz;
    if (abs(dot(n, view_vector(pos.xyz))) < u_view_cos) { o_bits = 0.0; return; }
    float inst = texelFetch(u_gb_material, px, 0).z;
    float tol = u_plane_tol * texelFetch(u_gb_depth, px, 0).r * float(u_scale);
    ivec2 grid = sample_grid();
    ivec2 cell = sample_cell(px);
    float bits = 0.0;
    for (int k = 0; k < 4; ++k) {
        ivec2 q = cell + ivec2(k & 1, k >> 1);
        if (any(lessThan(q, ivec2(0))) || any(greaterThanEqual(q, grid))) continue;
        ivec2 src = sample_pixel(q);
        vec4 ps = texelFetch(u_gb_position, src, 0);
        vec3 ns = texelFetch(u_gb_normal, src, 0).xyz;
        float is = texelFetch(u_gb_material, src, 0).z;
        bool same = ps.w != 0.0 && is == inst && dot(n, ns) >= u_normal_cos && abs(dot(n, ps.xyz - pos.xyz)) <= tol;
        if (same) bits += float(1 << k);
    }
    o_bits = bits;
}
#endif
