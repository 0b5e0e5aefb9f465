// Shadow-map mask: full-screen over the G-buffer; 1 = lit, 0 = shadowed, PCF fractions between.
#include "common/camera.glsl"
#include "common/gbuffer.glsl"

#ifdef VERTEX_SHADER
#include "common/fullscreen.glsl"
#endif

#ifdef FRAGMENT_SHADER
uniform sampler2D u_shadowmap;          // R32F atlas of linear light depths
uniform mat4 u_view_clip_from_rel[6];   // per view (sun/spot: 1, cube: 6 = +X -X +Y -Y +Z -Z)
uniform vec4 u_view_tile[6];            // x0, y0, size (texels), 0
uniform vec3 u_view_fwd[6];
uniform int u_cube;                     // 1: pick the view by the major axis from the light
uniform int u_ortho_light;              // 1: sun (orthographic, constant texel size)
uniform vec3 u_light_pos_rel;           // point/spot position, camera-relative
uniform vec3 u_light_dir;               // direction the light shines towards
uniform float u_texel_world;            // sun: metres per texel; others: per metre of depth
uniform float u_bias;                   // constant bias, texels
uniform float u_slope_bias;             // slope-scaled bias, texels
uniform float u_normal_offset;          // receiver offset along the normal, texels
uniform int u_pcf;                      // kernel radius in texels
uniform float u_max_distance;           // > 0: lit beyond this camera distance
layout(location = 0) out float o_mask;

void main() {
    ivec2 pix = ivec2(gl_FragCoord.xy);
    vec4 pos = texelFetch(u_gb_position, pix, 0);
    if (pos.w < 0.5) { o_mask = 1.0; return; }
    vec3 p = pos.xyz - u_cam_pos;
    if (u_max_distance > 0.0 && length(p) > u_max_distance) { o_mask = 1.0; return; }
    vec3 n = texelFetch(u_gb_normal, pix, 0).xyz;
    vec3 to_light = (u_ortho_light == 1) ? -u_light_dir : u_light_pos_rel - p;
    vec3 l = normalize(to_light);
    int view = 0;
    if (u_cube == 1) {
        vec3 d = -to_light;
        vec3 a = abs(d);
        if (a.x >= a.y && a.x >= a.z) view = d.x >= 0.0 ? 0 : 1;
        else if (a.y >= a.z) view = d.y >= 0.0 ? 2 : 3;
        else view = d.z >= 0.0 ? 4 : 5;
    }
    vec3 origin = (u_ortho_light == 1) ? vec3(0.0) : u_light_pos_rel;
    vec3 fwd = u_view_fwd[view];
    float texel = u_texel_world * ((u_ortho_light == 1) ? 1.0 : max(dot(p - origin, fwd), 1e-6));
    float c = clamp(dot(n, l), 0.0, 1.0);
    float tan_t = min(sqrt(max(1.0 - c * c, 0.0)) / max(c, 1e-3), 10.0);
    vec3 q = p + n * (texel * u_normal_offset);
    vec4 clip = u_view_clip_from_rel[view] * vec4(q, 1.0);
    vec2 uv = clip.xy / clip.w * 0.5 + 0.5;
    if (clip.w <= 0.0 || any(lessThan(uv, vec2(0.0))) || any(greaterThan(uv, vec2(1.0)))) {
        o_mask = 1.0;   // outside the map: beyond the fitted range / the spot cone
        return;
    }
    float receiver = dot(q - origin, fwd) - texel * (u_bias + u_slope_bias * tan_t);
    vec4 tile = u_view_tile[view];
    ivec2 lo = ivec2(tile.xy);
    ivec2 hi = lo + ivec2(tile.z) - 1;
    ivec2 centre = clamp(lo + ivec2(floor(uv * tile.z)), lo, hi);
    float lit = 0.0;
    float taps = 0.0;
    for (int dy = -u_pcf; dy <= u_pcf; ++dy) {
        for (int dx = -u_pcf; dx <= u_pcf; ++dx) {
            float occ = texelFetch(u_shadowmap, clamp(centre + ivec2(dx, dy), lo, hi), 0).r;
            lit += receiver <= occ ? 1.0 : 0.0;
            taps += 1.0;
        }
    }
    o_mask = lit / taps;
}
#endif
