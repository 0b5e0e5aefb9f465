/* scene_data.glsl -- the baked scene textures and the shadow-ray traversal that reads them.
 *
 * #version-less: the loader adds "#version 410 core" and the #defines of BakedScene.defines.
 * Packer: hybrid_shadow_addon/core/bake (baked.py, bvh.py, grid.py, update.py; twolevel.py, sah.py).
 * Oracle:  hybrid_shadow_addon/core/oracle/tracer.py (trace_structured mirrors this file step by step).
 * Two structures (BakeConfig.structure / Settings.structure): "grid" (textures [grid] .. [tri]
 * below, the walk in this file) and "bvh" (textures [node], [leaf], HS_STRUCTURE_BVH defined, the
 * walk in common/scene_bvh.glsl). Each bake holds the textures of its structure only.
 *
 * ============================== SCENE TEXTURE LAYOUT ======================================
 * Records are addressed by a linear texel index i, read by HS_FETCH(tex, i) below. Where the GL
 * has buffer textures that hold them (HS_TEXEL_BUFFERS, core/gpu/scene_textures.py), every
 * texture here is one (texel i = element i); else it is a 2D ARRAY texture, HS_TEX_WIDTH
 * (= 2^HS_TEX_WIDTH_LOG2 <= 16384) wide, of the same texels in the same order:
 *     x = i & (HS_TEX_WIDTH - 1);  row = i >> HS_TEX_WIDTH_LOG2;
 *     y = row & 16383;             layer = row >> 14              (hs_texel(i) below)
 * Height is the number of rows used (<= 16384), exactly 16384 when there are several layers.
 * Positions are in BAKE SPACE: world - BakedScene.origin (a round point near the casters when
 * they sit far from the world origin, else zero; see choose_origin in baked.py). Inverse world
 * matrices below map bake space to model space; rays must be given in bake space too.
 * "bits(f)" = the float32 bit pattern stored in a uint channel (uintBitsToFloat reads it back;
 * floats are never hidden in float textures as integers, so denormal flushing cannot bite).
 *
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
 * ---- structure "bvh" (two-level BVH, #define HS_STRUCTURE_BVH) ----
 * [node]  RGBA32UI "hs_node_tex", 1 texel per node: every model tree (BLAS), then the top-level
 *         tree over the instances (TLAS, [hs_tlas_root, hs_tlas_end)), each in depth-first
 *         pre-order (left child = node + 1). Boxes are 16-bit integers on the tree's grid,
 *         floor / ceil of the exact box (never smaller): model trees on the model's grid
 *         (p_q = (p_model - base) * inv_s, [leaf] frame), the top level on the scene's grid
 *         (p_q = (p_bake - hs_tlas_base) * hs_tlas_inv_scale); inv_s is a power of two.
 *     .x  qmin.x | qmin.y << 16      .y  qmin.z | qmax.x << 16      .z  qmax.y | qmax.z << 16
 *     .w  inner node: escape (absolute index of the node after its subtree);
 *         leaf: 0x80000000 | payload (a leaf's escape is node + 1). Top-level payload = instance
 *         id; model-tree payload = (first [leaf] texel << 3) | triangle count (1..HS_BVH_LEAF_SIZE).
 *     The walk widens each box per ray by e = 2^-20 |o_q|_1 (model trees) or 2^-18 (|o_q|_1 +
 *     hs_tlas_babs) (top level), which covers the rounding of o_q; top-level leaf boxes are the
 *     world box of the model box corners padded by 2^-18 (|box|_inf + extent) (float32 inverses).
 * [leaf]  RGBA32UI "hs_leaf_tex": instance records first (5 texels, texel 5 * id + k), then
 *         the model leaves' triangles; the shader reads max(5, ceil(9 HS_BVH_LEAF_SIZE / 4))
 *         texels from any record start (the texture has that much padding at its end).
 *     instance k=0..2  bits(row k of the inverse world matrix, bake space -> model space)
 *              k=3     .x model tree root [node], .y its end, .z model id | 0x80000000 if an
 *                      analytic sphere, .w 0
 *              k=4     mesh: bits(model grid base xyz, inv_s); sphere: bits(model-space sphere
 *                      centre xyz, radius rounded up)
 *     triangles: a leaf's triangles back to back, 9 floats each (bits of v0, v1, v2 in model
 *              space), ceil(9 count / 4) texels, read with static swizzles.
 * Uniforms: hs_tlas_base (vec3), hs_tlas_inv_scale, hs_tlas_babs (|base * inv_scale|_1),
 *   hs_tlas_root, hs_tlas_end. Defines: HS_STRUCTURE_BVH, HS_TEX_WIDTH(_LOG2), HS_TEX_ROWS_LOG2,
 *   HS_BVH_LEAF_SIZE, HS_HAS_MESHES / HS_HAS_SPHERES when the top level holds such casters.
 *
 * ---- both structures ----
 * Uniforms of "grid" (BakedScene.uniforms): hs_grid_origin (vec2, world x/y of the grid corner),
 *   hs_node_size[l] (base * 2^l), hs_level_dims[l] (ivec2), hs_level_offset[l],
 *   hs_level_count[l] (objects in level l; empty levels are skipped), hs_outside_node,
 *   hs_scene_max_height.
 * Defines (BakedScene.defines): HS_GRID_LEVELS, HS_TEX_WIDTH, HS_TEX_WIDTH_LOG2,
 *   HS_TEX_ROWS_LOG2 (14), HS_BVH_LEAF_SIZE, and HS_HAS_MESHES / HS_HAS_SPHERES only when the
 *   scene has such casters, HS_HAS_NODE_BVH only when some grid node has an object BVH,
 *   HS_HAS_ALPHA only with [uv] / [object_mat] (both structures; test with #ifdef).
 * =========================================================================================
 *
 * Ray convention: world-space origin o, direction d (not necessarily unit), occluded when any
 * caster is hit at t in (0, tmax), tmax in units of |d| ("infinite": pass any value >= 3e38).
 * Model-space rays are o' = Minv o, d' = Minv d with d' NOT renormalised, so t is shared.
 * hs_visibility(o, d, tmax): 1 lit, 0 occluded; with HS_HAS_ALPHA the product of the
 * transmittances (common/alpha.glsl hs_transmittance) of every alpha-cut triangle crossed in
 * (0, tmax), 0 at an opaque hit or once below HS_VIS_MIN. The grid walk tests every object at
 * most once per ray (each caster sits in exactly one grid node, the DDA visits a node at most
 * once, the outside node once, an object BVH each leaf once) and a model BVH each triangle at
 * most once, so no crossing is counted twice (a ray exactly through a shared edge hits both
 * triangles, as the oracle's watertight test does too).
 */

#ifndef HS_SCENE_DATA_GLSL
#define HS_SCENE_DATA_GLSL

#define HS_FLT_BIG 3.0e38      // clamp of tmax
#define HS_DDA_BIG 3.4e38      // "no boundary" t in the DDA
#define HS_SLAB_BIG 1.0e30     // 1/d for d == 0 in the slab test
#define HS_EPS16 1.52587890625e-05      // 2^-16
#define HS_TFAR_SCALE 1.00000095367431640625  // 1 + 2^-20
#define HS_PRETEST_EPS 3.814697265625e-06     // 2^-18
#define HS_OBVH_EPS 1.52587890625e-05         // 2^-16: object-BVH box widening (>= pre-test's)
#define HS_SPHERE_FLAG 0x80000000u

// ---------------------------------------------------------------- fetches (row wrapping) --
ivec3 hs_texel(int i)
{
    return ivec3(i & (HS_TEX_WIDTH - 1),
                 (i >> HS_TEX_WIDTH_LOG2) & ((1 << HS_TEX_ROWS_LOG2) - 1),
                 i >> (HS_TEX_WIDTH_LOG2 + HS_TEX_ROWS_LOG2));
}

// Record texel i of a scene texture. HS_TEXEL_BUFFERS (set by the GPU side, not the bake): the
// textures are buffer textures and i is the texel itself, one cheap fetch (on llvmpipe a 2D
// array fetch also computes mip, row and layer offsets: a node step costs a quarter more).
// Without it they are 2D array textures and hs_texel splits i into (x, y, layer).
#ifdef HS_TEXEL_BUFFERS
#define HS_USAMPLER usamplerBuffer
#define HS_SAMPLER samplerBuffer
#define HS_FETCH(tex, i) texelFetch(tex, i)
#else
#define HS_USAMPLER usampler2DArray
#define HS_SAMPLER sampler2DArray
#define HS_FETCH(tex, i) texelFetch(tex, hs_texel(i), 0)
#endif

// ---------------------------------------------------------------- primitive tests ---------
// Watertight ray/triangle (Woop, Benthin, Wald 2013). Set-up once per (ray, object).
struct HsWoop { ivec3 k; vec3 s; };

HsWoop hs_woop_setup(vec3 d)
{
    vec3 a = abs(d);
    int kz = (a.x > a.y) ? ((a.x > a.z) ? 0 : 2) : ((a.y > a.z) ? 1 : 2);
    int kx = kz + 1; if (kx == 3) kx = 0;
    int ky = kx + 1; if (ky == 3) ky = 0;
    if (d[kz] < 0.0) { int t = kx; kx = ky; ky = t; }
    HsWoop w;
    w.k = ivec3(kx, ky, kz);
    w.s = vec3(d[kx] / d[kz], d[ky] / d[kz], 1.0 / d[kz]);
    return w;
}

// Double-sided; hit iff t in (0, tmax). Edges exactly 0 count as inside (consistently, so a
// ray through a shared edge hits at least one of its triangles). bary: the hit's barycentric
// weights of v0, v1, v2 (the alpha test's UVs; compiled away where unused).
bool hs_triangle_hit_b(vec3 o, HsWoop w, vec3 v0, vec3 v1, vec3 v2, float tmax, out vec3 bary)
{
    bary = vec3(0.0);
    precise vec3 A = v0 - o;
    precise vec3 B = v1 - o;
    precise vec3 C = v2 - o;
    float Akz = A[w.k.z], Bkz = B[w.k.z], Ckz = C[w.k.z];
    precise float Ax = A[w.k.x] - w.s.x * Akz;
    precise float Ay = A[w.k.y] - w.s.y * Akz;
    precise float Bx = B[w.k.x] - w.s.x * Bkz;
    precise float By = B[w.k.y] - w.s.y * Bkz;
    precise float Cx = C[w.k.x] - w.s.x * Ckz;
    precise float Cy = C[w.k.y] - w.s.y * Ckz;
    precise float U = Cx * By - Cy * Bx;
    precise float V = Ax * Cy - Ay * Cx;
    precise float W = Bx * Ay - By * Ax;
    if ((U < 0.0 || V < 0.0 || W < 0.0) && (U > 0.0 || V > 0.0 || W > 0.0)) return false;
    precise float det = U + V + W;
    precise float T = (U * (w.s.z * Akz) + V * (w.s.z * Bkz)) + W * (w.s.z * Ckz);
    precise float td = tmax * det;
    bool hit = (det > 0.0) ? (T > 0.0 && T < td) : (det < 0.0 && T < 0.0 && T > td);
    if (hit) bary = vec3(U, V, W) / det;
    return hit;
}

bool hs_triangle_hit(vec3 o, HsWoop w, vec3 v0, vec3 v1, vec3 v2, float tmax)
{
    vec3 bary;
    return hs_triangle_hit_b(o, w, v0, v1, v2, tmax, bary);
}

// Ray/sphere surface hit with t in (0, tmax) (Ray Tracing Gems ch. 7; d need not be unit).
bool hs_sphere_hit(vec3 o, vec3 d, vec3 c, float r, float tmax)
{
    vec3 f = o - c;
    float a = dot(d, d);
    float b = -dot(f, d);
    vec3 l = f + (b / a) * d;
    float rr = r * r;
    float disc = rr - dot(l, l);
    if (disc < 0.0) return false;
    float cc = dot(f, f) - rr;
    float sq = sqrt(a * disc);
    float q = b + (b >= 0.0 ? sq : -sq);
    if (q == 0.0) return false;
    float t0 = cc / q;
    float t1 = q / a;
    return (t0 > 0.0 && t0 < tmax) || (t1 > 0.0 && t1 < tmax);
}

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

vec3 hs_slab_inv(vec3 d)
{
    return vec3(d.x != 0.0 ? 1.0 / d.x : HS_SLAB_BIG,
                d.y != 0.0 ? 1.0 / d.y : HS_SLAB_BIG,
                d.z != 0.0 ? 1.0 / d.z : HS_SLAB_BIG);
}

// Robust slab test: far t scaled by 1 + 2^-20 (Ize 2013), interval clipped to [0, tmax].
bool hs_slab_hit(vec3 o, vec3 inv, vec3 bmin, vec3 bmax, float tmax)
{
    vec3 t1 = (bmin - o) * inv;
    vec3 t2 = (bmax - o) * inv;
    vec3 tn3 = min(t1, t2), tf3 = max(t1, t2);
    float tn = max(max(tn3.x, tn3.y), tn3.z);
    float tf = min(min(tf3.x, tf3.y), tf3.z) * HS_TFAR_SCALE;
    return max(tn, 0.0) <= min(tf, tmax);
}

#ifdef HS_HAS_ALPHA
#include "common/alpha.glsl"
#endif

#ifdef HS_STRUCTURE_BVH
#include "common/scene_bvh.glsl"
#else
// ================================ hierarchical grid (structure "grid") ==================
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
// (common/alpha.glsl is included above, before the structure branch: the loader expands an
// include once, at its first textual occurrence, whatever #ifdef surrounds it)
uniform HS_SAMPLER hs_uv_tex;
uniform HS_USAMPLER hs_object_mat_tex;
#define HS_VIS_MIN 1.0e-3   // less light than this left: the ray is blocked (as scene_bvh.glsl)
// Light kept through the alpha-cut surfaces crossed so far by the current ray (reset by
// hs_occluded; the walk returns "occluded" once it falls below HS_VIS_MIN).
float hs_vis = 1.0;
#endif

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

#endif // HS_STRUCTURE_BVH

#endif // HS_SCENE_DATA_GLSL
