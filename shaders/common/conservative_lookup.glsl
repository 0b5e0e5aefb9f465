// Lookup in the conservative occupancy map of one light (passes/conservative.py,
// conservative_map.glsl): per texel a lower bound of the light depth of every caster in the
// texel's column. Used by raytrace.glsl (skip or shorten rays).
// Needs HS_LIGHT_SUN or HS_LIGHT_LOCAL.

uniform sampler2D u_cm;
uniform vec3 u_cm_origin;       // origin of the map's view coordinates, in bake space
uniform mat3 u_cm_basis[6];     // per view: columns right, up, forward (sun: view 0 only)
uniform vec4 u_cm_win[6];       // standard-coordinate window: lo.xy, texels per unit .zw
uniform vec4 u_cm_tile[6];      // atlas x0, y0, size, valid (0: view not built, trace fully)
uniform float u_cm_margin;      // depth slack (metres) for float rounding

// D: the lower bound of the caster depth in o's column, vz: o's own depth (bake-space o);
// false where o is outside the map (or the map's view was not built): no bound there.
bool cm_lookup(vec3 o, out float D, out float vz)
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
    vz = v.z;
    D = 0.0;
    if (tile.w > 0.5 && front && all(greaterThanEqual(tc, vec2(0.0))) && all(lessThan(tc, vec2(tile.z)))) {
        D = texelFetch(u_cm, ivec2(tile.xy) + ivec2(floor(tc)), 0).r - u_cm_margin;
        return true;
    }
    return false;
}
