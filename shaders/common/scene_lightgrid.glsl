/* scene_lightgrid.glsl -- a hard light's light-space grid (HS_LIGHT_GRID), on the two-level
 * BVH's scene (its triangle test and instance records). Bake and layout: core/bake/lightgrid.py;
 * numpy mirror: core/oracle/tracer/lightgrid.py trace_light_grid. Defines: HS_LG_LOCAL (a point, spot or
 * hard area light: a cube of directions; else a sun: a plane across it), HS_LG_TRIS (triangles
 * present), HS_LG_SPHERES (analytic sphere instances present).
 *
 * Every ray of the light lies on one line through it: it stays in one cell, whose list holds
 * every caster it can meet, highest key first. One flat loop over that list, an entry per
 * iteration, until a hit or the first key at or below the ray's own.
 */
#ifndef HS_SCENE_LIGHTGRID_GLSL
#define HS_SCENE_LIGHTGRID_GLSL

uniform HS_USAMPLER hs_lg_cell_tex;    // (first entry, count) per cell
uniform HS_USAMPLER hs_lg_entry_tex;   // (caster code, float bits of its key, box in the cell)
uniform HS_SAMPLER hs_lg_tri_tex;      // bake-space vertices, 3 texels per triangle
uniform float hs_lg_inv_cell;          // cells per grid unit
uniform ivec2 hs_lg_dims;              // cells (a cube: R x 6R, the faces one above the other)
uniform int hs_lg_tiles_x;             // cells are stored in 8 x 8 tiles, row-major
#ifdef HS_LG_LOCAL
uniform vec3 hs_lg_pos;                // the light (bake space, as u_light_vec)
#else
uniform vec3 hs_lg_ux;
uniform vec3 hs_lg_uy;
uniform vec3 hs_lg_dz;
uniform vec2 hs_lg_base;
#endif

// The grid position (in cells) and key of the ray from o along d; false: outside the grid
bool hs_lg_place(vec3 o, vec3 d, out vec2 g, out float s)
{
#ifdef HS_LG_LOCAL
    // the direction from the light: -d (d = light - o, as the trace computes it)
    vec3 w = -d;
    vec3 a = abs(w);
    vec2 uv;
    float z, face;
    if (a.x >= a.y && a.x >= a.z) { z = a.x; uv = w.yz; face = w.x > 0.0 ? 0.0 : 1.0; }
    else if (a.y >= a.z) { z = a.y; uv = w.zx; face = w.y > 0.0 ? 2.0 : 3.0; }
    else { z = a.z; uv = w.xy; face = w.z > 0.0 ? 4.0 : 5.0; }
    if (!(z > 0.0)) return false;
    uv = clamp(uv / z, -1.0, 1.0) + 1.0;
    float r = float(hs_lg_dims.x);
    // (a direction on the face's edge, uv 2, stays in the last cell, near its far side as the
    // entries' boxes expect)
    g = vec2(min(uv.x * hs_lg_inv_cell, r - 1.0 / 256.0), min(uv.y * hs_lg_inv_cell, r - 1.0 / 256.0) + face * r);
    s = -z;
    return true;
#else
    g = (vec2(dot(o, hs_lg_ux), dot(o, hs_lg_uy)) - hs_lg_base) * hs_lg_inv_cell;
    s = dot(o, hs_lg_dz);
    return g.x >= 0.0 && g.y >= 0.0 && g.x < float(hs_lg_dims.x) && g.y < float(hs_lg_dims.y);
#endif
}

// 1 = the ray o + t d, t in (0, tmax), meets nothing; 0 = blocked
float hs_lg_visibility(vec3 o, vec3 d, float tmax)
{
    tmax = min(tmax, HS_FLT_BIG);
    if (!(tmax > 0.0)) return 1.0;
    vec2 g;
    float s;
    if (!hs_lg_place(o, d, g, s)) return 1.0;
    ivec2 c = ivec2(g);
    int cell = (((c.y >> 3) * hs_lg_tiles_x + (c.x >> 3)) << 6) + ((c.y & 7) << 3) + (c.x & 7);
    uvec2 r = HS_FETCH(hs_lg_cell_tex, cell).xy;
    vec2 f = (g - vec2(c)) * 255.0;      // the ray within its cell, in the entries' box units
#ifdef HS_LG_TRIS
    HsShear sh = hs_shear_setup(d);
#endif
    int k = int(r.x);
    int end = k + int(r.y);
    bool blocked = false;
    while (k < end) {
        uvec3 e = HS_FETCH(hs_lg_entry_tex, k).xyz;
        if (uintBitsToFloat(e.y) <= s) break;   // this caster and all after it lie beyond the ray
        vec4 b = vec4(uvec4(e.z, e.z >> 8u, e.z >> 16u, e.z >> 24u) & 255u);
        if (f.x < b.x || f.x > b.y || f.y < b.z || f.y > b.w) { ++k; continue; }   // outside its box
#ifdef HS_LG_SPHERES
        if ((e.x & HS_SPHERE_FLAG) != 0u) {
            int at = 5 * int(e.x & 0x7FFFFFFFu);
            vec4 x0 = uintBitsToFloat(HS_FETCH(hs_leaf_tex, at));
            vec4 x1 = uintBitsToFloat(HS_FETCH(hs_leaf_tex, at + 1));
            vec4 x2 = uintBitsToFloat(HS_FETCH(hs_leaf_tex, at + 2));
            vec4 x4 = uintBitsToFloat(HS_FETCH(hs_leaf_tex, at + 4));
            blocked = hs_sphere_hit(hs_affine(x0, x1, x2, o), hs_linear(x0, x1, x2, d), x4.xyz, x4.w, tmax);
        } else
#endif
        {
#ifdef HS_LG_TRIS
            int t = 3 * int(e.x);
            blocked = hs_tri_hit(o, sh, HS_FETCH(hs_lg_tri_tex, t).xyz, HS_FETCH(hs_lg_tri_tex, t + 1).xyz,
                                 HS_FETCH(hs_lg_tri_tex, t + 2).xyz, tmax);
#endif
        }
        if (blocked) break;
        ++k;
    }
    return blocked ? 0.0 : 1.0;
}

#endif // HS_SCENE_LIGHTGRID_GLSL
