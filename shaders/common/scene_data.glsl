/* scene_data.glsl -- what every acceleration structure's textures and walk share: texel
 * addressing, the primitive tests, the alpha test's include; then the structure's own file.
 *
 * #version-less: the loader adds "#version 410 core" and the #defines of BakedScene.defines.
 * Packer: hybrid_shadow_addon/core/bake/structures (one AccelerationStructure per file below).
 * Oracle:  hybrid_shadow_addon/core/oracle/tracer/ (primitives.py mirrors the tests here; each walk its own module).
 * The structure (BakeConfig.structure / Settings.structure) picks its file by its define:
 *     HS_STRUCTURE_BVH   "bvh", common/scene_bvh.glsl  (textures [node], [leaf])
 *     HS_STRUCTURE_GRID  "grid", common/scene_grid.glsl (textures [grid] .. [tri])
 * Each bake holds the textures of its structure only; each file documents its own layout.
 *
 * ============================== SCENE TEXTURES (all structures) ===========================
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
 * Defines of every structure (BakedScene.defines): HS_TEX_WIDTH, HS_TEX_WIDTH_LOG2,
 *   HS_TEX_ROWS_LOG2 (14), HS_BVH_LEAF_SIZE, and HS_HAS_MESHES / HS_HAS_SPHERES only when the
 *   scene has such casters, HS_HAS_ALPHA only when some caster's material cuts its shadow (test
 *   with #ifdef).
 * =========================================================================================
 *
 * Ray convention: world-space origin o, direction d (not necessarily unit), occluded when any
 * caster is hit at t in (0, tmax), tmax in units of |d| ("infinite": pass any value >= 3e38).
 * Model-space rays are o' = Minv o, d' = Minv d with d' NOT renormalised, so t is shared.
 * hs_visibility(o, d, tmax): 1 lit, 0 occluded; with HS_HAS_ALPHA the product of the
 * transmittances (common/alpha.glsl hs_transmittance) of every alpha-cut triangle crossed in
 * (0, tmax), 0 at an opaque hit or once below HS_VIS_MIN. Every walk tests each object and each
 * triangle at most once per ray, so no crossing is counted twice (a ray exactly through a shared
 * edge hits both triangles, as the oracle's watertight test does too).
 */

#ifndef HS_SCENE_DATA_GLSL
#define HS_SCENE_DATA_GLSL

#define HS_FLT_BIG 3.0e38      // clamp of tmax
#define HS_SLAB_BIG 1.0e30     // 1/d for d == 0 in the slab test
#define HS_EPS16 1.52587890625e-05      // 2^-16
#define HS_TFAR_SCALE 1.00000095367431640625  // 1 + 2^-20
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

#include "common/linking.glsl"
#if defined(HS_STRUCTURE_BVH)
#include "common/scene_bvh.glsl"
#elif defined(HS_STRUCTURE_GRID)
#include "common/scene_grid.glsl"
#else
#error "no acceleration structure: compile with BakedScene.defines"
#endif

#endif // HS_SCENE_DATA_GLSL
