// Shadow-map mask: full-screen over the G-buffer; 1 = lit, 0 = shadowed, PCF fractions between.
//
// HS_PCSS (a light with a size, Settings.hard False): percentage-closer soft shadows (Fernando
// 2005), the filter shaped like the light. HS_SOFT_SHAPE as in common/soft_light.glsl: 0 a sun of
// angular radius atan(|u_light_u|), 1 a sphere of radius u_light_radius, 2 a rectangle, 3 an
// ellipse (half-extent axes u_light_u, u_light_v). Each tap is a point c of the light's unit
// shape (an R2 sequence, Cranley-Patterson rotated per pixel) and reads the map where the ray from
// the receiver to that point of the light crosses a depth z: the taps at depth z cover the light
// as seen from the receiver through that plane, the similar-triangles footprint. Depth z here
// is the light's own: along a sun's direction, along the line from a sphere light's centre to
// the receiver (the light's disk lies across it), along an area light's axis from its plane.
// (1) Blocker search at depth z_s, where the footprint spans u_max_kernel texels at the
// receiver (no nearer than the nearest caster can be), taps concentrated towards the centre.
// (2) The blockers' mean depth d_b gives the penumbra: the filter taps cross depth d_b, i.e. a
// kernel of radius (sun) tan(angle/2) (d_r - d_b) or (local) size (d_r - d_b) / d_b at the
// receiver, within u_pcf .. u_max_kernel texels. (3) PCF over them, each tap weighted as
// core/oracle/soft.py weights that point of the light. A tap is shadowed where the map holds a
// caster nearer than the receiver less the usual constant + slope bias, or nearer than the
// receiver's plane where that plane comes closer to the light at the tap (one-sided receiver-
// plane depth bias: wide kernels on sloped receivers do not shadow themselves).
// Without HS_PCSS the shader is the hard PCF below, unchanged; a pixel whose shading normal faces
// away from the light is 0 there, as in the ray-traced masks.
#include "common/camera.glsl"
#include "common/gbuffer.glsl"
#include "common/linking.glsl"
#ifdef HS_LINKING
uniform int u_link_receiver;   // the light's light set, -1: it lights every surface
#endif

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

#ifdef HS_PCSS
uniform vec3 u_light_u;                 // sun: tangent axis x tan(angle / 2); area: half-extent axes
uniform vec3 u_light_v;
uniform float u_light_radius;           // sphere light radius
uniform int u_search_taps;              // blocker-search taps
uniform int u_filter_taps;              // PCF taps
uniform float u_max_kernel;             // largest search / filter radius, texels at the receiver
uniform float u_depth_min;              // least light depth of a caster (see LightViews.depth_min)
uniform uint u_seed;                    // per light

uint hs_pcss_hash(uvec3 v)
{
    // pcg3d (Jarzynski & Olano 2020), first component
    v = v * 1664525u + 1013904223u;
    v.x += v.y * v.z; v.y += v.z * v.x; v.z += v.x * v.y;
    v ^= v >> 16u;
    v.x += v.y * v.z; v.y += v.z * v.x; v.z += v.x * v.y;
    return v.x;
}

// sample k of a pixel's sequence: R2 (Roberts 2018), shifted by a per-pixel hash
vec2 hs_pcss_xi(ivec2 px, int k, uint salt)
{
    uint h = hs_pcss_hash(uvec3(uvec2(px), u_seed ^ salt));
    uint h2 = hs_pcss_hash(uvec3(h, 0x9E3779B9u, u_seed));
    vec2 rot = vec2(float(h >> 8u), float(h2 >> 8u)) * (1.0 / 16777216.0);
    return fract(rot + float(k) * vec2(0.7548776662466927, 0.5698402909980532));
}

// a point of the light's unit shape: the square [-1, 1]^2 (rectangles) or the unit disk
vec2 hs_pcss_shape(vec2 xi)
{
    vec2 a = 2.0 * xi - 1.0;
#if HS_SOFT_SHAPE == 2
    return a;
#else
    if (a.x == 0.0 && a.y == 0.0) return vec2(0.0);
    float r, phi;
    if (abs(a.x) > abs(a.y)) { r = a.x; phi = 0.7853981633974483 * (a.y / a.x); }
    else { r = a.y; phi = 1.5707963267948966 - 0.7853981633974483 * (a.x / a.y); }
    return r * vec2(cos(phi), sin(phi));
#endif
}

// the sphere light's disk seen from q: radius (cone of its silhouette) and axes across q -> light
void hs_pcss_sphere(vec3 q, out float rad, out vec3 t1, out vec3 t2)
{
    vec3 w0 = u_light_pos_rel - q;
    float d2 = dot(w0, w0);
    float r2 = u_light_radius * u_light_radius;
    rad = u_light_radius * sqrt(d2 / max(d2 - r2, 1e-12 * d2));
    vec3 ax = w0 / sqrt(max(d2, 1e-30));
    t1 = normalize(abs(ax.x) > 0.5 ? cross(ax, vec3(0.0, 1.0, 0.0)) : cross(ax, vec3(1.0, 0.0, 0.0)));
    t2 = cross(ax, t1);
}

// point c of the light seen from q (normal n): d from q to it (sun: the unit direction) and the
// weight core/oracle/soft.py gives it (receiver cosine; area lights their cosine and 1/r^2 too)
void hs_pcss_light(vec2 c, vec3 q, vec3 n, out vec3 d, out float w)
{
#if HS_SOFT_SHAPE == 0
    d = normalize(-u_light_dir + c.x * u_light_u + c.y * u_light_v);
    w = max(dot(n, d), 0.0);
#elif HS_SOFT_SHAPE == 1
    float rad; vec3 t1, t2;
    hs_pcss_sphere(q, rad, t1, t2);
    d = u_light_pos_rel + rad * (c.x * t1 + c.y * t2) - q;
    w = max(dot(n, normalize(d)), 0.0);
#else
    d = u_light_pos_rel + c.x * u_light_u + c.y * u_light_v - q;
    float l2 = dot(d, d);
    w = max(dot(n, d), 0.0) * max(-dot(d, u_light_dir), 0.0) / max(l2 * l2, 1e-30);
#endif
}

// depth (along fwd) of the first caster on the map's line through x; 1e30 where none
float hs_pcss_map(vec3 x, vec3 origin, vec3 fwd)
{
    vec3 w = x - origin;
    int view = 0;
    if (u_cube == 1) {
        vec3 a = abs(w);
        if (a.x >= a.y && a.x >= a.z) view = w.x >= 0.0 ? 0 : 1;
        else if (a.y >= a.z) view = w.y >= 0.0 ? 2 : 3;
        else view = w.z >= 0.0 ? 4 : 5;
    }
    vec4 clip = u_view_clip_from_rel[view] * vec4(x, 1.0);
    if (clip.w <= 0.0) return 1e30;
    vec2 uv = clip.xy / clip.w * 0.5 + 0.5;
    if (any(lessThan(uv, vec2(0.0))) || any(greaterThan(uv, vec2(1.0)))) return 1e30;
    vec4 tile = u_view_tile[view];
    ivec2 lo = ivec2(tile.xy);
    ivec2 hi = lo + ivec2(tile.z) - 1;
    float s = texelFetch(u_shadowmap, clamp(lo + ivec2(floor(uv * tile.z)), lo, hi), 0).r;
    if (u_ortho_light == 1 || view == 0 && u_cube == 0) return s;
    return s * dot(w, fwd) / max(dot(w, u_view_fwd[view]), 1e-30);   // that face's axis -> fwd
}

// the receiver plane (q, n) on the map's line through x: its depth there less dq, within
// 10 x the lateral distance (the hard path's slope clamp)
float hs_pcss_plane(vec3 x, vec3 q, vec3 n, vec3 origin, vec3 fwd, float dq)
{
    if (u_ortho_light == 1) {
        vec3 lat = (x - q) - fwd * dot(x - q, fwd);
        float den = dot(fwd, n);
        float lim = 10.0 * length(lat);
        return abs(den) < 1e-6 ? lim : clamp(-dot(lat, n) / den, -lim, lim);
    }
    vec3 w = x - origin;
    float wf = dot(w, fwd);
    if (wf <= 0.0) return 0.0;
    float lim = 10.0 * length(origin + w * (dq / wf) - q);
    float s = dot(q - origin, n) / dot(w, n);   // the line o + s w meets the plane at s
    if (!(s > 0.0)) return lim;                 // never in front of the light: no receiver there
    return clamp(s * wf - dq, -lim, lim);
}

// the point where the ray q + t d (t in [0, tmax]) crosses light depth z (hq at q; the light
// depth is linear along the ray: dot with hax)
vec3 hs_pcss_at(vec3 q, vec3 d, float hq, float z, vec3 hax)
{
    float dh = dot(d, hax);
#if HS_SOFT_SHAPE == 0
    float tmax = 1e30;
#else
    float tmax = 1.0;
#endif
    float t = dh < 0.0 ? min((z - hq) / dh, tmax) : tmax;
    return q + d * max(t, 0.0);
}

// the light depth at which the light's footprint at the receiver (light depth hq) spans rho
// texels of tex metres
float hs_pcss_depth_for(float rho, float hq, float size, float tex)
{
    if (u_ortho_light == 1) return hq - rho * tex / max(size, 1e-9);
    return size * hq / (rho * tex + size);
}

float hs_pcss(ivec2 pix, vec3 q, vec3 n, vec3 origin, vec3 fwd, float bias, float tex)
{
    float dq = dot(q - origin, fwd);
    // "light depth" for the similar triangles, along hax from hor: sun, along its direction;
    // sphere, along the light -> receiver line (its disk lies across it); area, along its axis
    // (its plane at 0). size: the light's radius (sun: tan of its angular radius).
#if HS_SOFT_SHAPE == 0
    vec3 hax = u_light_dir, hor = vec3(0.0);
    float size = length(u_light_u);
#elif HS_SOFT_SHAPE == 1
    vec3 hax = normalize(q - u_light_pos_rel), hor = u_light_pos_rel;
    float size; vec3 t1, t2;
    hs_pcss_sphere(q, size, t1, t2);
#else
    vec3 hax = u_light_dir, hor = u_light_pos_rel;
    float size = max(length(u_light_u), length(u_light_v));
#endif
    float hq = dot(q - hor, hax);
#if HS_SOFT_SHAPE >= 2
    if (!(hq > 0.0)) return 0.0;   // behind an area light: no sample has weight
#endif
    // 1. blocker search
    float zs = min(max(hs_pcss_depth_for(u_max_kernel, hq, size, tex), u_depth_min), hq);
    float zsum = 0.0, nb = 0.0, sw = 0.0;
    for (int k = 0; k < u_search_taps; ++k) {
        vec2 c = hs_pcss_shape(hs_pcss_xi(pix, k, 0x5bd1e995u));
#if HS_SOFT_SHAPE == 2
        c *= max(abs(c.x), abs(c.y));   // denser towards the centre, where deep blockers are
#else
        c *= length(c);
#endif
        vec3 d; float w;
        hs_pcss_light(c, q, n, d, w);
        sw += w;
        vec3 x = hs_pcss_at(q, d, hq, zs, hax);
        float s = hs_pcss_map(x, origin, fwd);
        if (s >= dq + min(hs_pcss_plane(x, q, n, origin, fwd, dq), 0.0) - bias) continue;
        vec3 b = (u_ortho_light == 1) ? x + fwd * (s - dot(x, fwd))
                                      : origin + (x - origin) * (s / max(dot(x - origin, fwd), 1e-30));
        zsum += dot(b - hor, hax);
        nb += 1.0;
    }
    if (nb == 0.0) return sw > 0.0 ? 1.0 : 0.0;
    // 2. penumbra: the filter's taps cross the mean blocker depth, its footprint within limits
    float zf = clamp(zsum / nb, hs_pcss_depth_for(u_max_kernel, hq, size, tex),
                     hs_pcss_depth_for(float(u_pcf), hq, size, tex));
    // 3. PCF over the light's footprint
    float lit = 0.0;
    sw = 0.0;
    for (int k = 0; k < u_filter_taps; ++k) {
        vec2 c = hs_pcss_shape(hs_pcss_xi(pix, k, 0u));
        vec3 d; float w;
        hs_pcss_light(c, q, n, d, w);
        if (w <= 0.0) continue;
        vec3 x = hs_pcss_at(q, d, hq, zf, hax);
        float s = hs_pcss_map(x, origin, fwd);
        lit += s >= dq + min(hs_pcss_plane(x, q, n, origin, fwd, dq), 0.0) - bias ? w : 0.0;
        sw += w;
    }
    return sw > 0.0 ? lit / sw : 0.0;
}
#endif

void main() {
    ivec2 pix = ivec2(gl_FragCoord.xy);
    vec4 pos = texelFetch(u_gb_position, pix, 0);
    if (pos.w < 0.5) { o_mask = 1.0; return; }
    vec3 p = pos.xyz - u_cam_pos;
    if (u_max_distance > 0.0 && length(p) > u_max_distance) { o_mask = 1.0; return; }
#ifdef HS_LINKING
    // HS_LINKING: a surface the light's receiver collection leaves out is unlit (its casters
    // were drawn filtered by its blocker collection: shadowmap.py)
    if (!hs_link_receives(int(texelFetch(u_gb_material, pix, 0).z + 0.5), u_link_receiver)) { o_mask = 0.0; return; }
#endif
    vec3 n = texelFetch(u_gb_normal, pix, 0).xyz;
    vec3 to_light = (u_ortho_light == 1) ? -u_light_dir : u_light_pos_rel - p;
    vec3 l = normalize(to_light);
#ifndef HS_PCSS
    // as the ray-traced masks (common/shadow_ray.glsl): unlit where the shading normal faces away
    if (dot(texelFetch(u_gb_shading, pix, 0).xyz, to_light) <= 0.0) { o_mask = 0.0; return; }
#endif
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
#ifdef HS_PCSS
    o_mask = hs_pcss(pix, q, n, origin, fwd, texel * (u_bias + u_slope_bias * tan_t), texel);
    return;
#endif
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
