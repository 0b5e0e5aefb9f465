// Pass 2, ray traced: one shadow ray per mask texel towards one light, through the baked scene.
//
// Output (R32F): 1 = lit, 0 = shadowed. Background texels are 1 (the lighting pass skips them).
// Texels whose surface faces away from the light, or that the light cannot reach (outside a
// spot's cone, behind an area light) are 0 without a ray: unlit anyway.
// Defines (besides scene_data.glsl's): HS_LIGHT_SUN or HS_LIGHT_LOCAL (point, spot, area) picks
// the light kind, one program per kind; HS_MAX_DISTANCE (shadows only on surfaces within
// u_max_distance of the camera, as the shadow-map pass; rays are no longer than that either), HS_INTERLACE (trace only the texels of
// phase u_phase in each 2x2 block; keep u_history where that texel's phase is in
// u_valid_phases, else write -1 for interlace_fill.glsl to fill from this frame's rays),
// HS_CONSERVATIVE (a conservative occupancy map of the light decides or shortens the ray).

#ifdef VERTEX_SHADER
#include "common/fullscreen.glsl"
#endif

#ifdef FRAGMENT_SHADER
#include "common/camera.glsl"
#include "common/gbuffer.glsl"
#include "common/scene_data.glsl"

uniform int u_scale;            // mask texel = u_scale x u_scale full-resolution pixels
uniform ivec2 u_full_size;      // G-buffer size
uniform vec3 u_light_vec;       // sun: unit direction towards it; else the light's position
                                // (bake space: world - the bake's origin)
uniform vec3 u_cam_bake;        // camera position in bake space (float64 on the CPU)
#ifdef HS_LIGHT_LOCAL
uniform vec3 u_light_axis;      // unit direction the light shines towards
uniform float u_light_cone;     // no light where dot(light -> p, axis) <= this: a spot's
                                // cos(size / 2), 0 behind an area light, -2 (never) for a point
#endif
#ifdef HS_MAX_DISTANCE
uniform float u_max_distance;
#endif
#ifdef HS_CONSERVATIVE
// Conservative occupancy map of this light (passes/conservative.py, conservative_map.glsl):
// per texel a lower bound of the light depth of every caster in the texel's column.
uniform sampler2D u_cm;
uniform vec3 u_cm_origin;       // origin of the map's view coordinates, in bake space
uniform mat3 u_cm_basis[6];     // per view: columns right, up, forward (sun: view 0 only)
uniform vec4 u_cm_win[6];       // standard-coordinate window: lo.xy, texels per unit .zw
uniform vec4 u_cm_tile[6];      // atlas x0, y0, size, valid (0: view not built, trace fully)
uniform float u_cm_margin;      // depth slack (metres) for float rounding
#endif
#ifdef HS_INTERLACE
uniform sampler2D u_history;
uniform int u_phase;            // 0..3
uniform int u_valid_phases;     // bit p set: history texels of phase p are up to date
#endif

in vec2 v_uv;
out float o_mask;

// Ray origin pushed off the surface along the normal (Waechter & Binder, Ray Tracing Gems ch. 6):
// a fixed number of float ULPs of each coordinate (scale-invariant, works far from the origin),
// a small absolute step near the origin where ULPs vanish. 'slack' adds the G-buffer
// reconstruction error, which grows with the distance from the camera.
vec3 offset_origin(vec3 p, vec3 n, float slack)
{
    const float origin = 1.0 / 32.0;
    const float float_scale = 1.0 / 65536.0;
    const float int_scale = 256.0;
    ivec3 of_i = ivec3(int_scale * n);
    vec3 p_i = vec3(intBitsToFloat(floatBitsToInt(p.x) + ((p.x < 0.0) ? -of_i.x : of_i.x)),
                    intBitsToFloat(floatBitsToInt(p.y) + ((p.y < 0.0) ? -of_i.y : of_i.y)),
                    intBitsToFloat(floatBitsToInt(p.z) + ((p.z < 0.0) ? -of_i.z : of_i.z)));
    vec3 q = vec3(abs(p.x) < origin ? p.x + float_scale * n.x : p_i.x,
                  abs(p.y) < origin ? p.y + float_scale * n.y : p_i.y,
                  abs(p.z) < origin ? p.z + float_scale * n.z : p_i.z);
    return q + n * slack;
}

// The surface point of pixel px in bake space: the camera ray scaled to the G-buffer's view
// depth, added to the camera's bake-space position. Rebuilt camera-relative, it keeps float32
// precision wherever the scene sits in the world (100 km out as well as at the origin).
vec3 surface_point(ivec2 px, float depth)
{
    vec3 o_rel, dir;
    camera_ray(vec2(px) + 0.5, o_rel, dir);
    vec3 p_rel = (u_ortho == 1) ? o_rel + dir * (depth - u_clip_start) : dir * (depth / u_clip_start);
    return u_cam_bake + p_rel;
}

void main()
{
    ivec2 mt = ivec2(gl_FragCoord.xy);
#ifdef HS_INTERLACE
    int phase = (mt.x & 1) | ((mt.y & 1) << 1);
    ivec2 block_ray = (mt & ~1) + ivec2(u_phase & 1, u_phase >> 1);
    bool block_has_ray = all(lessThan(block_ray, textureSize(u_history, 0)));
    if (phase != u_phase && block_has_ray) {  // (a block cut by the edge traces its own texels)
        o_mask = ((u_valid_phases >> phase) & 1) != 0 ? texelFetch(u_history, mt, 0).r : -1.0;
        return;
    }
#endif
    ivec2 px = mask_source_pixel(mt, u_scale, u_full_size);
    if (texelFetch(u_gb_position, px, 0).w == 0.0) { o_mask = 1.0; return; }
    float depth = texelFetch(u_gb_depth, px, 0).r;
    vec3 p = surface_point(px, depth);
#ifdef HS_MAX_DISTANCE
    if (distance(p, u_cam_bake) > u_max_distance) { o_mask = 1.0; return; }
#endif
    vec3 n = texelFetch(u_gb_normal, px, 0).xyz;
#ifdef HS_LIGHT_LOCAL
    vec3 to_light = u_light_vec - p;
#else
    vec3 to_light = u_light_vec;
#endif
    float facing = dot(n, to_light);
    if (facing <= 0.0) { o_mask = 0.0; return; }    // faces away: unlit, no ray
#ifdef HS_LIGHT_LOCAL
    if (dot(-normalize(to_light), u_light_axis) <= u_light_cone) { o_mask = 0.0; return; }  // out of reach
#endif

    vec3 o = offset_origin(p, n, depth * 3.0e-6);
#ifdef HS_LIGHT_LOCAL
    vec3 d = u_light_vec - o;     // the light is at t = 1
    float tmax = 1.0;
#else
    vec3 d = u_light_vec;
    float tmax = HS_FLT_BIG;
#endif
#ifdef HS_MAX_DISTANCE
    tmax = min(tmax, u_max_distance / length(d));
#endif
#ifdef HS_CONSERVATIVE
    // The ray stays in o's column of the map; casters there lie at depth >= D, so a hit needs
    // the ray's depth >= D: cut tmax there, or skip the ray when o is nearer the light than D.
    {
        vec3 rel = o - u_cm_origin;
        int view = 0;
#ifdef HS_LIGHT_LOCAL
        vec3 a = abs(rel);
        if (a.x >= a.y && a.x >= a.z) view = rel.x >= 0.0 ? 0 : 1;
        else if (a.y >= a.z) view = rel.y >= 0.0 ? 2 : 3;
        else view = rel.z >= 0.0 ? 4 : 5;
#endif
        vec4 tile = u_cm_tile[view];
        vec3 v = rel * u_cm_basis[view];
#ifdef HS_LIGHT_LOCAL
        vec2 s = v.xy / v.z;
        bool front = v.z > 0.0;
#else
        vec2 s = v.xy;
        bool front = true;
#endif
        vec4 win = u_cm_win[view];
        vec2 tc = (s - win.xy) * win.zw;
        if (tile.w > 0.5 && front && all(greaterThanEqual(tc, vec2(0.0))) && all(lessThan(tc, vec2(tile.z)))) {
            float D = texelFetch(u_cm, ivec2(tile.xy) + ivec2(floor(tc)), 0).r - u_cm_margin;
            if (D >= v.z) { o_mask = 1.0; return; }
#ifdef HS_LIGHT_LOCAL
            tmax = min(tmax, 1.0 - D / v.z);
#else
            tmax = min(tmax, (v.z - D) / -dot(d, u_cm_basis[0][2]));
#endif
        }
    }
#endif
    o_mask = hs_occluded(o, d, tmax) ? 0.0 : 1.0;
}
#endif
