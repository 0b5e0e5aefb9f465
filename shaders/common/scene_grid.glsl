/* scene_grid.glsl -- the thesis' hierarchical grid (HS_STRUCTURE_GRID, structure "grid"): its
 * textures and the walk that reads them; included by scene_data.glsl (shared fetches and tests).
 * Packer: hybrid_shadow_addon/core/bake/structures/grid.py, grid_update.py (HierarchicalGrid).
 * Oracle:  hybrid_shadow_addon/core/oracle/tracer/grid.py (trace_grid mirrors this file step by step).
 *
 * ============================== GRID TEXTURE LAYOUT ======================================
 * [grid]  RGBA32UI "hs_grid_tex", 1 texel per node. Node ids are global: level l starts at
 *         hs_level_offset[l], node (ix, iy) of level l = hs_level_offset[l] + iy * nx + ix,
 *         nx, ny = hs_level_dims[l]; the last node (hs_outside_node) holds casters outside the
 *         grid rectangle and is tested by every ray.
 *     .x  offset of the node's list in [grid_index]
 *     .y  count (objects in the node)
 *     .z  bits(max height): highest world bounding-sphere top (z) of its objects, rounded up;
 *         -FLT_MAX when empty
 *     .w  object BVH: 0 = none (test the node's list flat), else 1 + its root node in [bvh].
 *         Nodes with more than BakeConfig.object_bvh_threshold objects have one; their list in
 *         [grid_index] is then in the tree's leaf order (Morton order of the object centres).
 * [grid_index]  RG32UI "hs_grid_index_tex", 1 texel per entry, node lists packed back to back
 *         (any length; spare slots and a spare tail for incremental updates, capacities CPU-side).
 *     .x  object id (instance index, row of [object])
 *     .y  model id | 0x80000000 if the instance is an analytic sphere primitive
 * [object]  RGBA32F "hs_object_tex", 4 texels per instance (texel 4*id + k), all instances
 *         (non-casters too: the id is the scene's instance index).
 *     k=0..2  row k of the inverse world matrix (xyzw): p_model[k] = dot(row_k, vec4(p_world, 1))
 *     k=3     world bounding sphere: xyz centre, w radius (enlarged by 2^-20 relative, rounded up)
 * [model]  RGBA32UI "hs_model_tex", 2 texels per model (texel 2*id + k).
 *     k=0     bits(model-space bounding sphere): xyz centre, w radius (rounded up)
 *     k=1     .x BVH root node (absolute index in [bvh]), .y BVH node count (0: no triangles),
 *             .z first triangle (absolute index in [tri]), .w triangle count
 * [bvh]  RGBA32UI "hs_bvh_tex", 2 texels per node (texel 2*node + k), every model's tree in
 *         depth-first pre-order (left child = node + 1), boxes in model space, rounded outward
 *         and enlarged by 2^-20 relative.
 *     k=0     .xyz bits(box min), .w escape: absolute index of the node after this subtree
 *     k=1     .xyz bits(box max), .w leaf: 0 for an inner node, else (first triangle << 3) | count
 *             (count 1..7, triangles contiguous in [tri])
 *         Object BVHs of crowded grid nodes follow the model trees (and the tail after model
 *         edits) in the same record format: boxes in BAKE space around the objects' stored world
 *         spheres ([object] k=3, rounded outward, enlarged like model boxes), balanced over the
 *         Morton-ordered list, escape absolute, and the root's escape ends the walk; a leaf is
 *         (first [grid_index] entry << 3) | count (count 1..7, entries contiguous). The walk
 *         (hs_node_bvh_occludes) widens every box by HS_OBVH_EPS * (|o|_1 + |root min|_1 +
 *         |root max|_1) per ray, which bounds the sphere pre-test's own tolerance: the tree never
 *         culls an object the pre-test would accept.
 * [tri]  RGB32F "hs_tri_tex", 3 texels per triangle (texel 3*tri + k): vertex k in model space,
 *         triangles reordered per model into BVH leaf order. De-indexed on purpose: the thesis'
 *         vertex + index textures cost one more dependent fetch per vertex in the innermost loop;
 *         here the "vertex texture" holds each triangle's three vertices directly.
 * -- alpha-cut shadows only (HS_HAS_ALPHA: some caster's material cuts its shadow; opaque scenes
 *    have neither texture; the materials are [mat] / [atlas] of common/alpha.glsl) --
 * [uv]  RGBA32F "hs_uv_tex", 2 texels per [tri] record (texel 2*tri + k), mirroring [tri]: the
 *         mesh UVs of the triangle's corners, k=0 (u0 v0 u1 v1), k=1 (u2 v2 0 0). Filled for
 *         the models of alpha-cut casters (Scene.alpha_models), zeros elsewhere.
 * [object_mat]  R32UI "hs_object_mat_tex", 1 texel per instance (texel id, all instances as
 *         [object]): 1 + the material index (a [mat] record) when the walk runs the any-hit
 *         alpha test on the instance's triangles (its material cuts its shadow and its model's
 *         UVs are in [uv]), 0: opaque (also for analytic spheres). A texture of its own rather
 *         than a spare field: [object] and [grid_index] have none, and only alpha scenes pay
 *         for the fetch.
 *
 * Uniforms (BakedScene.uniforms): hs_grid_origin (vec2, world x/y of the grid corner),
 *   hs_node_size[l] (base * 2^l), hs_level_dims[l] (ivec2), hs_level_offset[l],
 *   hs_level_count[l] (objects in level l; empty levels are skipped), hs_outside_node,
 *   hs_scene_max_height.
 * Defines: HS_STRUCTURE_GRID, HS_GRID_LEVELS, the shared ones (scene_data.glsl),
 *   HS_HAS_NODE_BVH only when some grid node has an object BVH; HS_HAS_ALPHA comes with
 *   [uv] / [object_mat].
 *
 * The grid walk tests every object at most once per ray (each caster sits in exactly one grid
 * node, the DDA visits a node at most once, the outside node once, an object BVH each leaf once)
 * and a model BVH each triangle at most once.
 */
#ifndef HS_SCENE_GRID_GLSL
#define HS_SCENE_GRID_GLSL

#define HS_DDA_BIG 3.4e38      // "no boundary" t in the DDA
#define HS_PRETEST_EPS 3.814697265625e-06     // 2^-18
#define HS_OBVH_EPS 1.52587890625e-05         // 2^-16: object-BVH box widening (>= pre-test's)

uniform HS_USAMPLER hs_grid_tex;
uniform HS_USAMPLER hs_grid_index_tex;
uniform HS_SAMPLER hs_object_tex;
uniform HS_USAMPLER hs_model_tex;
uniform HS_USAMPLER hs_bvh_tex;
uniform HS_SAMPLER hs_tri_tex;

uniform vec2 hs_grid_origin;
uniform float hs_node_size[HS_GRID_LEVELS];
uniform ivec2 hs_level_dims[HS_GRID_LEVELS];
uniform int hs_level_offset[HS_GRID_LEVELS];
uniform int hs_level_count[HS_GRID_LEVELS];
uniform int hs_outside_node;
uniform float hs_scene_max_height;

uvec4 hs_fetch_grid(int node)        { return HS_FETCH(hs_grid_tex, node); }
uvec2 hs_fetch_index(int entry)      { return HS_FETCH(hs_grid_index_tex, entry).xy; }
vec4  hs_fetch_object(int obj, int k){ return HS_FETCH(hs_object_tex, 4 * obj + k); }
uvec4 hs_fetch_model(int model, int k){ return HS_FETCH(hs_model_tex, 2 * model + k); }
#if defined(HS_HAS_MESHES) || defined(HS_HAS_NODE_BVH)
uvec4 hs_fetch_bvh(int node, int k)  { return HS_FETCH(hs_bvh_tex, 2 * node + k); }
#endif
vec3  hs_fetch_vertex(int tri, int k){ return HS_FETCH(hs_tri_tex, 3 * tri + k).xyz; }

#ifdef HS_HAS_ALPHA
// (common/alpha.glsl is included by scene_data.glsl, before the structure's file: the loader
// expands an include once, at its first textual occurrence, whatever #ifdef surrounds it)
uniform HS_SAMPLER hs_uv_tex;
uniform HS_USAMPLER hs_object_mat_tex;
#define HS_VIS_MIN 1.0e-3   // less light than this left: the ray is blocked (as scene_bvh.glsl)
// Light kept through the alpha-cut surfaces crossed so far by the current ray (reset by
// hs_occluded; the walk returns "occluded" once it falls below HS_VIS_MIN).
float hs_vis = 1.0;
#endif

// Conservative: does the segment o + t d, t in [0, tmax], pass within r of c?
bool hs_sphere_pretest(vec3 o, vec3 d, vec4 sph, float tmax)
{
    vec3 f = o - sph.xyz;
    float a = dot(d, d);
    float tc = clamp(-dot(f, d) / a, 0.0, tmax);
    vec3 p = f + tc * d;
    vec3 af = abs(f), ad = abs(d);
    float e = HS_PRETEST_EPS * ((af.x + af.y + af.z) + tc * (ad.x + ad.y + ad.z));
    float re = sph.w + e;
    return dot(p, p) <= re * re;
}

// ---------------------------------------------------------------- BVH ---------------------
#ifdef HS_HAS_MESHES
// Stackless walk in depth-first order: box hit -> next node (inner) or test the leaf then
// escape; box miss -> escape. Any hit ends the walk; with HS_HAS_ALPHA, an object whose
// material mat (>= 0) cuts its shadow instead multiplies hs_vis by each crossed triangle's
// transmittance at the hit's UV ([uv]) and ends the walk once hs_vis < HS_VIS_MIN.
bool hs_bvh_occluded(vec3 o, vec3 d, int root, int count, float tmax, int mat)
{
    HsWoop w = hs_woop_setup(d);
    vec3 inv = hs_slab_inv(d);
    int i = root;
    int end = root + count;
    while (i < end) {
        uvec4 n0 = hs_fetch_bvh(i, 0);
        uvec4 n1 = hs_fetch_bvh(i, 1);
        bool hit = hs_slab_hit(o, inv, uintBitsToFloat(n0.xyz), uintBitsToFloat(n1.xyz), tmax);
        if (hit && n1.w != 0u) {
            int first = int(n1.w >> 3u);
            int cnt = int(n1.w & 7u);
            for (int k = 0; k < cnt; ++k) {
                int t = first + k;
                vec3 b;
                if (hs_triangle_hit_b(o, w, hs_fetch_vertex(t, 0), hs_fetch_vertex(t, 1),
                                      hs_fetch_vertex(t, 2), tmax, b)) {
#ifdef HS_HAS_ALPHA
                    if (mat < 0) return true;
                    vec4 p = HS_FETCH(hs_uv_tex, 2 * t);
                    vec4 q = HS_FETCH(hs_uv_tex, 2 * t + 1);
                    hs_vis *= hs_transmittance(mat, b.x * p.xy + b.y * p.zw + b.z * q.xy);
                    if (hs_vis < HS_VIS_MIN) return true;
#else
                    return true;
#endif
                }
            }
        }
        i = (hit && n1.w == 0u) ? i + 1 : int(n0.w);
    }
    return false;
}
#endif

// ---------------------------------------------------------------- objects -----------------
// One grid-index entry: world-sphere pre-test, ray to model space, sphere or BVH.
bool hs_object_occludes(vec3 o, vec3 d, float tmax, uvec2 entry)
{
    int obj = int(entry.x);
#ifdef HS_LINKING
    if (!hs_link_blocks(obj)) return false;   // not the traced light's blocker
#endif
    if (!hs_sphere_pretest(o, d, hs_fetch_object(obj, 3), tmax)) return false;
    vec4 r0 = hs_fetch_object(obj, 0);
    vec4 r1 = hs_fetch_object(obj, 1);
    vec4 r2 = hs_fetch_object(obj, 2);
    precise vec3 om = vec3(((r0.x * o.x + r0.y * o.y) + r0.z * o.z) + r0.w,
                           ((r1.x * o.x + r1.y * o.y) + r1.z * o.z) + r1.w,
                           ((r2.x * o.x + r2.y * o.y) + r2.z * o.z) + r2.w);
    precise vec3 dm = vec3((r0.x * d.x + r0.y * d.y) + r0.z * d.z,
                           (r1.x * d.x + r1.y * d.y) + r1.z * d.z,
                           (r2.x * d.x + r2.y * d.y) + r2.z * d.z);
    int model = int(entry.y & 0x7FFFFFFFu);
#ifdef HS_HAS_SPHERES
    if ((entry.y & HS_SPHERE_FLAG) != 0u) {
        vec4 sph = uintBitsToFloat(hs_fetch_model(model, 0));
        return hs_sphere_hit(om, dm, sph.xyz, sph.w, tmax);
    }
#endif
#ifdef HS_HAS_MESHES
    uvec4 info = hs_fetch_model(model, 1);
    if (info.y == 0u) return false;
    int mat = -1;
#ifdef HS_HAS_ALPHA
    mat = int(HS_FETCH(hs_object_mat_tex, obj).x) - 1;
#endif
    return hs_bvh_occluded(om, dm, int(info.x), int(info.y), tmax, mat);
#else
    return false;
#endif
}

#ifdef HS_HAS_NODE_BVH
// Object BVH of a crowded grid node: stackless walk like hs_bvh_occluded, leaves are runs of
// grid-index entries. Boxes widened by e (see [bvh]) so no pre-test hit is culled.
bool hs_node_bvh_occludes(vec3 o, vec3 d, float tmax, int root)
{
    vec3 inv = hs_slab_inv(d);
    uvec4 r0 = hs_fetch_bvh(root, 0);
    uvec4 r1 = hs_fetch_bvh(root, 1);
    vec3 ao = abs(o);
    vec3 rlo = abs(uintBitsToFloat(r0.xyz));
    vec3 rhi = abs(uintBitsToFloat(r1.xyz));
    float e = HS_OBVH_EPS * (((ao.x + ao.y) + ao.z) + (((rlo.x + rlo.y) + rlo.z) + ((rhi.x + rhi.y) + rhi.z)));
    vec3 ev = vec3(e);
    int i = root;
    int end = int(r0.w);
    while (i < end) {
        uvec4 n0 = hs_fetch_bvh(i, 0);
        uvec4 n1 = hs_fetch_bvh(i, 1);
        bool hit = hs_slab_hit(o, inv, uintBitsToFloat(n0.xyz) - ev, uintBitsToFloat(n1.xyz) + ev, tmax);
        if (hit && n1.w != 0u) {
            int first = int(n1.w >> 3u);
            int cnt = int(n1.w & 7u);
            for (int k = 0; k < cnt; ++k)
                if (hs_object_occludes(o, d, tmax, hs_fetch_index(first + k))) return true;
        }
        i = (hit && n1.w == 0u) ? i + 1 : int(n0.w);
    }
    return false;
}
#endif

// All objects of one grid node; zmin: lowest ray z inside the node (-FLT_MAX: no culling).
bool hs_node_occludes(vec3 o, vec3 d, float tmax, int node, float zmin, bool cull)
{
    uvec4 g = hs_fetch_grid(node);
    if (g.y == 0u) return false;
    if (cull) {
        float maxh = uintBitsToFloat(g.z);
        if (zmin - maxh > HS_EPS16 * (abs(zmin) + abs(maxh))) return false;
    }
#ifdef HS_HAS_NODE_BVH
    if (g.w != 0u) return hs_node_bvh_occludes(o, d, tmax, int(g.w) - 1);
#endif
    int first = int(g.x);
    int cnt = int(g.y);
    for (int k = 0; k < cnt; ++k)
        if (hs_object_occludes(o, d, tmax, hs_fetch_index(first + k))) return true;
    return false;
}

// ---------------------------------------------------------------- grid DDA ----------------
// One level: clip the ray [0, t_dda] to the grid rectangle, start in the (clamped) cell of the
// entry point, then step cell by cell (Amanatides & Woo), branching on zero components.
bool hs_walk_level(vec3 o, vec3 d, float tmax, float t_dda, int lvl)
{
    float s = hs_node_size[lvl];
    int nx = hs_level_dims[lvl].x, ny = hs_level_dims[lvl].y;
    int off = hs_level_offset[lvl];
    float u0 = (o.x - hs_grid_origin.x) / s;
    float v0 = (o.y - hs_grid_origin.y) / s;
    float du = d.x / s;
    float dv = d.y / s;
    float t_lo = 0.0, t_hi = t_dda;
    float invu = 0.0, invv = 0.0;
    if (du == 0.0) {
        if (u0 < 0.0 || u0 > float(nx)) return false;
    } else {
        invu = 1.0 / du;
        float ta = (0.0 - u0) * invu, tb = (float(nx) - u0) * invu;
        t_lo = max(t_lo, min(ta, tb));
        t_hi = min(t_hi, max(ta, tb));
    }
    if (dv == 0.0) {
        if (v0 < 0.0 || v0 > float(ny)) return false;
    } else {
        invv = 1.0 / dv;
        float ta = (0.0 - v0) * invv, tb = (float(ny) - v0) * invv;
        t_lo = max(t_lo, min(ta, tb));
        t_hi = min(t_hi, max(ta, tb));
    }
    if (!(t_lo <= t_hi)) return false;
    int cx = clamp(int(floor(u0 + du * t_lo)), 0, nx - 1);
    int cy = clamp(int(floor(v0 + dv * t_lo)), 0, ny - 1);
    int sx = du > 0.0 ? 1 : -1;
    int sy = dv > 0.0 ? 1 : -1;
    float dmax = max(abs(du), abs(dv));
    float inv_dmax = dmax > 0.0 ? 1.0 / dmax : HS_DDA_BIG;
    float slack = (abs(u0) + abs(v0) + 2.0) * inv_dmax;
    float t_enter = t_lo;
    for (int step = 0; step < nx + ny + 2; ++step) {
        float tx = du > 0.0 ? (float(cx + 1) - u0) * invu : (du < 0.0 ? (float(cx) - u0) * invu : HS_DDA_BIG);
        float ty = dv > 0.0 ? (float(cy + 1) - v0) * invv : (dv < 0.0 ? (float(cy) - v0) * invv : HS_DDA_BIG);
        float t_exit = min(min(tx, ty), t_hi);
        // lowest z of the ray inside the cell, t widened a little for rounding
        float delta = HS_EPS16 * (t_exit - t_enter + slack);
        float zmin = d.z > 0.0 ? o.z + d.z * max(t_enter - delta, 0.0)
                   : (d.z < 0.0 ? o.z + d.z * min(t_exit + delta, tmax) : o.z);
        if (hs_node_occludes(o, d, tmax, off + cy * nx + cx, zmin, true)) return true;
        if (t_exit >= t_hi) break;
        if (tx <= ty) cx += sx; else cy += sy;
        if (cx < 0 || cx >= nx || cy < 0 || cy >= ny) break;
        t_enter = t_exit;
    }
    return false;
}

// The shadow-ray query: true when a caster is hit at t in (0, tmax) (HS_HAS_ALPHA: an opaque
// one, or the light kept through alpha-cut ones, hs_vis, fell below HS_VIS_MIN).
bool hs_occluded(vec3 o, vec3 d, float tmax)
{
#ifdef HS_HAS_ALPHA
    hs_vis = 1.0;
#endif
    tmax = min(tmax, HS_FLT_BIG);
    if (!(tmax > 0.0) || (d.x == 0.0 && d.y == 0.0 && d.z == 0.0)) return false;
    float H = hs_scene_max_height;
    // above every caster and going up (or flat): lit
    if (o.z - H > HS_EPS16 * (abs(o.z) + abs(H)) && d.z >= 0.0) return false;
    float t_dda = tmax;
    if (d.z > 0.0) {
        float t_top = ((H - o.z) + HS_EPS16 * (abs(H) + abs(o.z))) / d.z * (1.0 + HS_EPS16);
        t_dda = min(tmax, max(t_top, 0.0));
    }
    if (hs_node_occludes(o, d, tmax, hs_outside_node, 0.0, false)) return true;
    for (int l = 0; l < HS_GRID_LEVELS; ++l) {
        if (hs_level_count[l] == 0) continue;
        if (hs_walk_level(o, d, tmax, t_dda, l)) return true;
    }
    return false;
}

#ifdef HS_HAS_ALPHA
// Visibility in [0, 1]: the product of the transmittances of every alpha-cut surface the ray
// crosses in (0, tmax), 0 at an opaque one.
float hs_visibility(vec3 o, vec3 d, float tmax) { return hs_occluded(o, d, tmax) ? 0.0 : hs_vis; }
#else
float hs_visibility(vec3 o, vec3 d, float tmax) { return hs_occluded(o, d, tmax) ? 0.0 : 1.0; }
#endif

#endif // HS_SCENE_GRID_GLSL
