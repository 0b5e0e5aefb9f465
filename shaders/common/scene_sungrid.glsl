/* scene_sungrid.glsl -- a hard sun's light-space grid (HS_SUN_GRID), on the two-level BVH's
 * scene (its triangle test and instance records). Bake and layout: core/bake/sungrid.py; numpy
 * mirror: sungrid.trace_sun_grid. Defines: HS_SG_TRIS (triangles present), HS_SG_SPHERES
 * (analytic sphere instances present).
 *
 * Every ray of the sun is parallel to hs_sg_dz: it stays in the grid cell of its origin across
 * the sun, whose list holds every caster it can meet, highest towards the sun first. One flat
 * loop over that list: an entry per iteration, until a hit or the first caster whose highest
 * point lies below the origin's depth.
 */
#ifndef HS_SCENE_SUNGRID_GLSL
#define HS_SCENE_SUNGRID_GLSL

uniform HS_USAMPLER hs_sg_cell_tex;    // (first entry, count) per cell
uniform HS_USAMPLER hs_sg_entry_tex;   // (caster code, float bits of its key, box in the cell)
uniform HS_SAMPLER hs_sg_tri_tex;      // bake-space vertices, 3 texels per triangle
uniform vec3 hs_sg_ux;
uniform vec3 hs_sg_uy;
uniform vec3 hs_sg_dz;
uniform vec2 hs_sg_base;
uniform float hs_sg_inv_cell;
uniform ivec2 hs_sg_dims;
uniform int hs_sg_tiles_x;             // cells are stored in 8 x 8 tiles, row-major

// 1 = the ray o + t d, t in (0, tmax), d the sun's direction, meets nothing; 0 = blocked
float hs_sg_visibility(vec3 o, vec3 d, float tmax)
{
    tmax = min(tmax, HS_FLT_BIG);
    if (!(tmax > 0.0)) return 1.0;
    vec2 g = (vec2(dot(o, hs_sg_ux), dot(o, hs_sg_uy)) - hs_sg_base) * hs_sg_inv_cell;
    if (!(g.x >= 0.0 && g.y >= 0.0 && g.x < float(hs_sg_dims.x) && g.y < float(hs_sg_dims.y))) return 1.0;
    ivec2 c = ivec2(g);
    int cell = (((c.y >> 3) * hs_sg_tiles_x + (c.x >> 3)) << 6) + ((c.y & 7) << 3) + (c.x & 7);
    uvec2 r = HS_FETCH(hs_sg_cell_tex, cell).xy;
    float so = dot(o, hs_sg_dz);
    vec2 f = (g - vec2(c)) * 255.0;      // o within its cell, in the entries' box units
#ifdef HS_SG_TRIS
    HsShear sh = hs_shear_setup(d);
#endif
    int k = int(r.x);
    int end = k + int(r.y);
    bool blocked = false;
    while (k < end) {
        uvec3 e = HS_FETCH(hs_sg_entry_tex, k).xyz;
        if (uintBitsToFloat(e.y) <= so) break;   // this caster and all after it lie below o
        vec4 b = vec4(uvec4(e.z, e.z >> 8u, e.z >> 16u, e.z >> 24u) & 255u);
        if (f.x < b.x || f.x > b.y || f.y < b.z || f.y > b.w) { ++k; continue; }   // o outside its box
#ifdef HS_SG_SPHERES
        if ((e.x & HS_SPHERE_FLAG) != 0u) {
            int at = 5 * int(e.x & 0x7FFFFFFFu);
            vec4 x0 = uintBitsToFloat(HS_FETCH(hs_leaf_tex, at));
            vec4 x1 = uintBitsToFloat(HS_FETCH(hs_leaf_tex, at + 1));
            vec4 x2 = uintBitsToFloat(HS_FETCH(hs_leaf_tex, at + 2));
            vec4 x4 = uintBitsToFloat(HS_FETCH(hs_leaf_tex, at + 4));
            vec3 m_o = hs_affine(x0, x1, x2, o);
            precise vec3 m_d = vec3((x0.x * d.x + x0.y * d.y) + x0.z * d.z,
                                    (x1.x * d.x + x1.y * d.y) + x1.z * d.z,
                                    (x2.x * d.x + x2.y * d.y) + x2.z * d.z);
            blocked = hs_sphere_hit(m_o, m_d, x4.xyz, x4.w, tmax);
        } else
#endif
        {
#ifdef HS_SG_TRIS
            int t = 3 * int(e.x);
            blocked = hs_tri_hit(o, sh, HS_FETCH(hs_sg_tri_tex, t).xyz, HS_FETCH(hs_sg_tri_tex, t + 1).xyz,
                                 HS_FETCH(hs_sg_tri_tex, t + 2).xyz, tmax);
#endif
        }
        if (blocked) break;
        ++k;
    }
    return blocked ? 0.0 : 1.0;
}

#endif // HS_SCENE_SUNGRID_GLSL
