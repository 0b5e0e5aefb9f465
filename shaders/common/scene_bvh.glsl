/* scene_bvh.glsl -- the two-level BVH (HS_STRUCTURE_BVH, structure "bvh"): its textures and
 * the walk that reads them; included by scene_data.glsl (shared fetches and tests).
 * Packer: hybrid_shadow_addon/core/bake/structures/twolevel.py, blas.py, tlas.py, wide.py (TwoLevelBVH).
 * Oracle: hybrid_shadow_addon/core/oracle/tracer/twolevel.py (trace_twolevel mirrors the binary walk
 * step by step), wide.py (trace_wide_packed: the 4-wide walk).
 *
 * ============================== BVH TEXTURE LAYOUT =======================================
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
 * [uv]  RGBA32F "hs_uv_tex" (HS_HAS_ALPHA only): the UVs of alpha-cut models' triangles at the
 *         same [leaf] texels as their triangles (6 floats per triangle).
 * [wide] RGBA32UI "hs_wide_tex" (HS_BVH_WIDE only): the same trees as 4-wide nodes, the block of
 *         binary inner node i at an even depth of its tree in texels 2i .. 2i+3 (see hs_trace
 *         below; packer: structures/wide.py). Single rays walk it; packets walk [node].
 */
#ifndef HS_SCENE_BVH_GLSL
#define HS_SCENE_BVH_GLSL

#define HS_LEAF_FLAG 0x80000000u
#define HS_QEPS 9.5367431640625e-07     // 2^-20: per-ray widening of model boxes, x |o_q|_1
#define HS_TLAS_EPS 3.814697265625e-06  // 2^-18: per-ray widening of top-level boxes
#define HS_TFLOOR 1.9073486328125e-06   // 2^-19: nearest hit, x the vertices' reach along the ray

uniform HS_USAMPLER hs_node_tex;
uniform HS_USAMPLER hs_leaf_tex;
uniform vec3 hs_tlas_base;
uniform float hs_tlas_inv_scale;
uniform float hs_tlas_babs;
uniform int hs_tlas_root;
uniform int hs_tlas_end;

// A node's six 16-bit corners as floats without an int-to-float conversion (a slow path on
// many GPUs): the bits of 2^23 + q, less 2^23, are q exactly (precise: the subtraction is
// not to be merged with the slab test's).
vec3 hs_qlo(uvec4 n)
{
    precise vec3 q = uintBitsToFloat(uvec3(n.x & 0xFFFFu, n.x >> 16u, n.y & 0xFFFFu) | 0x4B000000u) - 8388608.0;
    return q;
}
vec3 hs_qhi(uvec4 n)
{
    precise vec3 q = uintBitsToFloat(uvec3(n.y >> 16u, n.z & 0xFFFFu, n.z >> 16u) | 0x4B000000u) - 8388608.0;
    return q;
}

// Slab test against a quantised node: box = integer corners, ray = (lo, hi) origin planes
// (o_q + e, o_q - e: the box widened by e) and 1/d_q; far t scaled like hs_slab_hit.
bool hs_qbox_hit(vec3 rlo, vec3 rhi, vec3 inv, uvec4 n, float tmax)
{
    vec3 blo = hs_qlo(n);
    vec3 bhi = hs_qhi(n);
    vec3 t1 = (blo - rlo) * inv;
    vec3 t2 = (bhi - rhi) * inv;
    vec3 tn3 = min(t1, t2), tf3 = max(t1, t2);
    float tn = max(max(tn3.x, tn3.y), tn3.z);
    float tf = min(min(tf3.x, tf3.y), tf3.z) * HS_TFAR_SCALE;
    return max(tn, 0.0) <= min(tf, tmax);
}

#ifdef HS_HAS_MESHES
// The watertight test's permutation and shear as three rows (set up once per instance), so
// the triangle test reads no component by a per-ray index: dot(mx, A) == A[kx] - Sx A[kz]
// exactly (the other terms are exact zeros), dot(mz, A) == A[kz].
struct HsShear { vec3 mx; vec3 my; vec3 mz; float sz; };

HsShear hs_shear_setup(vec3 d)
{
    vec3 a = abs(d);
    int kz = (a.x > a.y) ? ((a.x > a.z) ? 0 : 2) : ((a.y > a.z) ? 1 : 2);
    int kx = kz + 1; if (kx == 3) kx = 0;
    int ky = kx + 1; if (ky == 3) ky = 0;
    float dz = d[kz];
    if (dz < 0.0) { int t = kx; kx = ky; ky = t; }
    vec3 ex = vec3(kx == 0, kx == 1, kx == 2);
    vec3 ey = vec3(ky == 0, ky == 1, ky == 2);
    vec3 ez = vec3(kz == 0, kz == 1, kz == 2);
    float sx = d[kx] / dz, sy = d[ky] / dz;
    HsShear s;
    s.mx = ex - sx * ez;
    s.my = ey - sy * ez;
    s.mz = ez;
    s.sz = 1.0 / dz;
    return s;
}

float hs_row(vec3 m, vec3 a) { precise float r = (m.x * a.x + m.y * a.y) + m.z * a.z; return r; }

// bary: the hit's barycentric weights of v0, v1, v2 (set on a hit)
bool hs_tri_hit_b(vec3 o, HsShear s, vec3 v0, vec3 v1, vec3 v2, float tmax, out vec3 bary)
{
    bary = vec3(0.0);
    precise vec3 A = v0 - o;
    precise vec3 B = v1 - o;
    precise vec3 C = v2 - o;
    precise float Akz = hs_row(s.mz, A), Bkz = hs_row(s.mz, B), Ckz = hs_row(s.mz, C);
    precise float Ax = hs_row(s.mx, A), Ay = hs_row(s.my, A);
    precise float Bx = hs_row(s.mx, B), By = hs_row(s.my, B);
    precise float Cx = hs_row(s.mx, C), Cy = hs_row(s.my, C);
    precise float U = Cx * By - Cy * Bx;
    precise float V = Ax * Cy - Ay * Cx;
    precise float W = Bx * Ay - By * Ax;
    if ((U < 0.0 || V < 0.0 || W < 0.0) && (U > 0.0 || V > 0.0 || W > 0.0)) return false;
    precise float det = U + V + W;
    precise float T = (U * (s.sz * Akz) + V * (s.sz * Bkz)) + W * (s.sz * Ckz);
    precise float td = tmax * det;
    // hits nearer than the float32 error of T (which grows with the vertices' distance along
    // the ray axis) are the receiver's own surface: a 5 km ground triangle under a ray that
    // leaves it 16 um up would otherwise shadow itself
    precise float tfloor = HS_TFLOOR * max(max(abs(Akz), abs(Bkz)), abs(Ckz)) * abs(s.sz);
    bool hit = (det > 0.0) ? (T > tfloor * det && T < td) : (det < 0.0 && T < tfloor * det && T > td);
    if (hit) bary = vec3(U, V, W) / det;
    return hit;
}

bool hs_tri_hit(vec3 o, HsShear s, vec3 v0, vec3 v1, vec3 v2, float tmax)
{
    vec3 bary;
    return hs_tri_hit_b(o, s, v0, v1, v2, tmax, bary);
}

// One leaf: up to HS_BVH_LEAF_SIZE (<= 4) triangles, 9 floats each back to back in the texels
// a..l (static swizzles; texels past the leaf size are not read).
bool hs_leaf_hit(vec3 o, HsShear s, int cnt, vec4 a, vec4 b, vec4 c, vec4 d, vec4 e, vec4 g, vec4 h,
                 vec4 k, vec4 l, float tmax)
{
    if (hs_tri_hit(o, s, a.xyz, vec3(a.w, b.xy), vec3(b.zw, c.x), tmax)) return true;
#if HS_BVH_LEAF_SIZE > 1
    if (cnt > 1 && hs_tri_hit(o, s, c.yzw, d.xyz, vec3(d.w, e.xy), tmax)) return true;
#endif
#if HS_BVH_LEAF_SIZE > 2
    if (cnt > 2 && hs_tri_hit(o, s, vec3(e.zw, g.x), g.yzw, h.xyz, tmax)) return true;
#endif
#if HS_BVH_LEAF_SIZE > 3
    if (cnt > 3 && hs_tri_hit(o, s, vec3(h.w, k.xy), vec3(k.zw, l.x), l.yzw, tmax)) return true;
#endif
    return false;
}

#ifdef HS_HAS_ALPHA
#include "common/alpha.glsl"
// [uv] RGBA32F: the UVs of an alpha-cut model's triangles at the same texels as the triangles
// in [leaf], 6 floats each back to back (u0 v0 u1 v1 u2 v2)
uniform HS_SAMPLER hs_uv_tex;
#define HS_VIS_MIN 1.0e-3   // less light than this left: the ray is blocked

// The light a ray keeps through triangle k (barycentrics b) of the leaf at [leaf] texel at,
// cut by c.
float hs_cut_tri(HsCut c, int at, int k, vec3 b)
{
    int t = at + (3 * k) / 2;
    vec4 p = HS_FETCH(hs_uv_tex, t);
    vec4 q = HS_FETCH(hs_uv_tex, t + 1);
    bool odd = (k & 1) != 0;
    vec2 a0 = odd ? p.zw : p.xy, a1 = odd ? q.xy : p.zw, a2 = odd ? q.zw : q.xy;
    return hs_cut_transmit(c, b.x * a0 + b.y * a1 + b.z * a2);
}

// One leaf's light: 0 at a hit of an uncut instance (cut false), else the product of the cut
// triangles' transmittances. Each triangle is tested once, for both kinds.
float hs_leaf_vis(vec3 o, HsShear s, int cnt, vec4 a, vec4 b, vec4 c, vec4 d, vec4 e, vec4 g,
                  vec4 h, vec4 k, vec4 l, float tmax, HsCut cut, bool cuts, int at)
{
    float t = 1.0;
    vec3 w;
    if (hs_tri_hit_b(o, s, a.xyz, vec3(a.w, b.xy), vec3(b.zw, c.x), tmax, w)) t = cuts ? hs_cut_tri(cut, at, 0, w) : 0.0;
#if HS_BVH_LEAF_SIZE > 1
    if (cnt > 1 && t > 0.0 && hs_tri_hit_b(o, s, c.yzw, d.xyz, vec3(d.w, e.xy), tmax, w))
        t *= cuts ? hs_cut_tri(cut, at, 1, w) : 0.0;
#endif
#if HS_BVH_LEAF_SIZE > 2
    if (cnt > 2 && t > 0.0 && hs_tri_hit_b(o, s, vec3(e.zw, g.x), g.yzw, h.xyz, tmax, w))
        t *= cuts ? hs_cut_tri(cut, at, 2, w) : 0.0;
#endif
#if HS_BVH_LEAF_SIZE > 3
    if (cnt > 3 && t > 0.0 && hs_tri_hit_b(o, s, vec3(h.w, k.xy), vec3(k.zw, l.x), l.yzw, tmax, w))
        t *= cuts ? hs_cut_tri(cut, at, 3, w) : 0.0;
#endif
    return t;
}
#define HS_TRACE_T float
#define HS_BLOCKED 0.0
#define HS_UNBLOCKED vis
#else
#define HS_TRACE_T bool
#define HS_BLOCKED true
#define HS_UNBLOCKED false
#endif
#else
#define HS_TRACE_T bool
#define HS_BLOCKED true
#define HS_UNBLOCKED false
#endif

// The record at [leaf] texel at: an instance (5 texels) or a model leaf's triangles (9 floats
// each), read as the same max(5, ceil(9 HS_BVH_LEAF_SIZE / 4)) texels either way (x3 is u3's bits)
void hs_leaf_record(int at, out vec4 x0, out vec4 x1, out vec4 x2, out uvec4 u3, out vec4 x3,
                    out vec4 x4, out vec4 x5, out vec4 x6, out vec4 x7, out vec4 x8)
{
    x0 = uintBitsToFloat(HS_FETCH(hs_leaf_tex, at));
    x1 = uintBitsToFloat(HS_FETCH(hs_leaf_tex, at + 1));
    x2 = uintBitsToFloat(HS_FETCH(hs_leaf_tex, at + 2));
    u3 = HS_FETCH(hs_leaf_tex, at + 3);
    x3 = uintBitsToFloat(u3);
    x4 = uintBitsToFloat(HS_FETCH(hs_leaf_tex, at + 4));
    x5 = vec4(0.0); x6 = vec4(0.0); x7 = vec4(0.0); x8 = vec4(0.0);
#if defined(HS_HAS_MESHES) && HS_BVH_LEAF_SIZE > 2
    x5 = uintBitsToFloat(HS_FETCH(hs_leaf_tex, at + 5));
    x6 = uintBitsToFloat(HS_FETCH(hs_leaf_tex, at + 6));
#endif
#if defined(HS_HAS_MESHES) && HS_BVH_LEAF_SIZE > 3
    x7 = uintBitsToFloat(HS_FETCH(hs_leaf_tex, at + 7));
    x8 = uintBitsToFloat(HS_FETCH(hs_leaf_tex, at + 8));
#endif
}

// The point p moved by the affine map of rows r0..r2 (an instance's inverse world matrix)
vec3 hs_affine(vec4 r0, vec4 r1, vec4 r2, vec3 p)
{
    precise vec3 q = vec3(((r0.x * p.x + r0.y * p.y) + r0.z * p.z) + r0.w,
                          ((r1.x * p.x + r1.y * p.y) + r1.z * p.z) + r1.w,
                          ((r2.x * p.x + r2.y * p.y) + r2.z * p.z) + r2.w);
    return q;
}

// The direction d moved by the linear part of the same map
vec3 hs_linear(vec4 r0, vec4 r1, vec4 r2, vec3 d)
{
    precise vec3 q = vec3((r0.x * d.x + r0.y * d.y) + r0.z * d.z,
                          (r1.x * d.x + r1.y * d.y) + r1.z * d.z,
                          (r2.x * d.x + r2.y * d.y) + r2.z * d.z);
    return q;
}

// The ray (bake space) on the top level's grid: its origin planes (lo, hi: o_q widened by the
// top level's e) and 1 / d_q.
void hs_tlas_ray(vec3 o, vec3 d, out vec3 lo, out vec3 hi, out vec3 inv)
{
    precise vec3 toq = (o - hs_tlas_base) * hs_tlas_inv_scale;
    vec3 ta = abs(toq);
    precise float te = HS_TLAS_EPS * (((ta.x + ta.y) + ta.z) + hs_tlas_babs);
    precise vec3 t_lo = toq + vec3(te);
    precise vec3 t_hi = toq - vec3(te);
    lo = t_lo; hi = t_hi;
    inv = hs_slab_inv(d * hs_tlas_inv_scale);
}

// The model-space ray (m_o, m_d) on its model tree's grid (frame: base xyz, inv_s), as above
// with the model trees' e.
void hs_model_ray(vec3 m_o, vec3 m_d, vec4 frame, out vec3 lo, out vec3 hi, out vec3 inv)
{
    precise vec3 oq = (m_o - frame.xyz) * frame.w;
    vec3 aq = abs(oq);
    precise float e = HS_QEPS * ((aq.x + aq.y) + aq.z);
    precise vec3 qlo = oq + vec3(e);
    precise vec3 qhi = oq - vec3(e);
    lo = qlo; hi = qhi;
    inv = hs_slab_inv(m_d * frame.w);
}

// Nodes from i on, until a leaf whose box the ray hits (true: w is its word, i the node after
// it) or the end of the tree (i >= limit). (A flag, not a nested break: llvmpipe miscompiled the
// break out of this inner loop, lanes lost their node index.) Its body is the walk's cost on a
// SIMD software rasteriser, which runs every branch of it for all lanes: it has none.
bool hs_walk(inout int i, inout uint w, int limit, vec3 q_lo, vec3 q_hi, vec3 q_inv, float tmax)
{
    bool found = false;
    bool walking = i < limit;
    while (walking) {
        uvec4 n = HS_FETCH(hs_node_tex, i);
        bool leaf = (n.w & HS_LEAF_FLAG) != 0u;
        bool hit = hs_qbox_hit(q_lo, q_hi, q_inv, n, tmax);
        found = hit && leaf;
        w = n.w;
        i = (hit || leaf) ? i + 1 : int(n.w);   // (a leaf found: i is the node after it)
        walking = !found && i < limit;
    }
    return found;
}

// The shadow-ray query, "while-while" (Aila & Laine 2009): the inner loop walks nodes (top level
// or model tree, one node per iteration) until the ray hits a leaf; the outer loop handles that
// leaf (an instance: enter its model tree; a model leaf: its triangles) and resumes. The model
// tree's end returns the walk to the top-level node after the instance's leaf. Per ray the nodes
// are visited in the same order as by one flat loop; the split only keeps the leaf work out of
// the node steps (a SIMD software rasteriser runs every branch of a loop body for all lanes).
HS_TRACE_T hs_trace_binary(vec3 o, vec3 d, float tmax)
{
#ifdef HS_HAS_ALPHA
    float vis = 1.0;   // light kept through the alpha-cut surfaces crossed so far
    int amat = 0;      // 1 + material of the current instance when it cuts its shadow
    HsCut cut = hs_cut_setup(0);
#endif
    tmax = min(tmax, HS_FLT_BIG);
    if (!(tmax > 0.0) || (d.x == 0.0 && d.y == 0.0 && d.z == 0.0)) return HS_UNBLOCKED;
    vec3 t_lo, t_hi, t_inv;
    hs_tlas_ray(o, d, t_lo, t_hi, t_inv);
    vec3 q_lo = t_lo, q_hi = t_hi, q_inv = t_inv;
    int i = hs_tlas_root;
    int ret = -1;   // >= 0: inside a model tree, resume the top level there
#ifdef HS_HAS_MESHES
    vec3 om = vec3(0.0);
    HsShear sh;
    sh.mx = vec3(0.0); sh.my = vec3(0.0); sh.mz = vec3(0.0); sh.sz = 0.0;
#endif
    int limit = hs_tlas_end;   // the end of the tree being walked (the top level's, or the model tree's)
    for (;;) {
        // nodes until a leaf; the return from a model tree to the top level is tested here,
        // once a walk ends, not at every node (a sixth less time), and walks on at once
        uint w = 0u;
        bool found = hs_walk(i, w, limit, q_lo, q_hi, q_inv, tmax);
        if (!found && ret >= 0) {   // the model tree's end: on along the top level
            i = ret; ret = -1; q_lo = t_lo; q_hi = t_hi; q_inv = t_inv; limit = hs_tlas_end;
            found = hs_walk(i, w, limit, q_lo, q_hi, q_inv, tmax);
        }
        if (!found) break;
        uint pay = w & 0x7FFFFFFFu;
        int next = i;
#ifdef HS_LINKING
        if (ret < 0 && !hs_link_blocks(int(pay))) continue;   // not the light's blocker: on
#endif
        int at = ret < 0 ? 5 * int(pay) : int(pay >> 3u);
        vec4 x0, x1, x2, x3, x4, x5, x6, x7, x8;
        uvec4 u3;
        hs_leaf_record(at, x0, x1, x2, u3, x3, x4, x5, x6, x7, x8);
        if (ret < 0) {
            vec3 m_o = hs_affine(x0, x1, x2, o);
            vec3 m_d = hs_linear(x0, x1, x2, d);
            bool is_sphere = (u3.z & HS_SPHERE_FLAG) != 0u;
#ifdef HS_HAS_SPHERES
            if (is_sphere && hs_sphere_hit(m_o, m_d, x4.xyz, x4.w, tmax)) return HS_BLOCKED;
#endif
#ifdef HS_HAS_MESHES
            if (!is_sphere) {
                hs_model_ray(m_o, m_d, x4, q_lo, q_hi, q_inv);
                om = m_o;
                sh = hs_shear_setup(m_d);
                ret = next;
                next = int(u3.x);
                limit = int(u3.y);
#ifdef HS_HAS_ALPHA
                amat = int(u3.w);
                if (amat != 0) cut = hs_cut_setup(amat - 1);
#endif
            }
#endif
        }
#ifdef HS_HAS_MESHES
        else {
#ifdef HS_HAS_ALPHA
            vis *= hs_leaf_vis(om, sh, int(pay & 7u), x0, x1, x2, x3, x4, x5, x6, x7, x8, tmax, cut, amat != 0, at);
            if (vis < HS_VIS_MIN) return HS_BLOCKED;
#else
            if (hs_leaf_hit(om, sh, int(pay & 7u), x0, x1, x2, x3, x4, x5, x6, x7, x8, tmax)) return HS_BLOCKED;
#endif
        }
#endif
        i = next;
    }
    return HS_UNBLOCKED;
}

#ifdef HS_BVH_WIDE
// [wide] RGBA32UI: 4-wide nodes, the block of binary inner node i (an even depth of its tree) in
// texels 2i .. 2i+3: its children (grandchildren, or leaf children) in tree order, each its
// binary node's texel with .w = the leaf's word, or the child's own [node] index (its block),
// or 0 for no child. Packer: hybrid_shadow_addon/core/bake/structures/wide.py.
// Oracle: hybrid_shadow_addon/core/oracle/tracer/wide.py (trace_wide_packed).
uniform HS_USAMPLER hs_wide_tex;
#ifndef HS_WIDE_STACK
#define HS_WIDE_STACK 32   // stack entries per ray (a fuller one: the binary walk instead)
#endif
#define HS_WIDE_RETURN 0x7FFFFFFFu   // a stack entry: the model tree is done, back to the top level

// What a tree's walk starts from: its root's block, or the root's leaf word for a one-leaf tree.
uint hs_wide_root(int root, int end) { return end - root == 1 ? HS_FETCH(hs_node_tex, root).w : uint(root); }

// The shadow-ray query on 4-wide nodes with a stack, "while-while" as the binary walk: the inner
// loop pops wide nodes (and the returns from model trees) until a leaf pops; the outer loop
// handles the leaf as the binary walk does (its code repeated line for line: written as a shared
// function, llvmpipe rounded the alpha-cut transmittances differently). A wide node's children
// whose boxes the ray hits are pushed so that they pop in tree order, so the leaves are met in
// the binary walk's order (the same product of transmittances); the pushes are stores at the top
// that only the hits keep (no branch). A ray whose stack would overflow is traced again by the
// binary walk.
HS_TRACE_T hs_trace(vec3 o, vec3 d, float tmax)
{
#ifdef HS_HAS_ALPHA
    float vis = 1.0;
    int amat = 0;
    HsCut cut = hs_cut_setup(0);
#endif
    tmax = min(tmax, HS_FLT_BIG);
    if (!(tmax > 0.0) || (d.x == 0.0 && d.y == 0.0 && d.z == 0.0)) return HS_UNBLOCKED;
    vec3 t_lo, t_hi, t_inv;
    hs_tlas_ray(o, d, t_lo, t_hi, t_inv);
    vec3 q_lo = t_lo, q_hi = t_hi, q_inv = t_inv;
#ifdef HS_HAS_MESHES
    vec3 om = vec3(0.0);
    HsShear sh;
    sh.mx = vec3(0.0); sh.my = vec3(0.0); sh.mz = vec3(0.0); sh.sz = 0.0;
#endif
    uint stack[HS_WIDE_STACK];
    int top = 0;
    if (hs_tlas_end > hs_tlas_root) stack[top++] = hs_wide_root(hs_tlas_root, hs_tlas_end);
    bool inside = false;   // in a model tree (its entries sit above a HS_WIDE_RETURN)
    bool found = top > 0;
    while (found) {
        uint e = 0u;
        bool over = false;
        bool walking = true;
        while (walking) {
            e = stack[--top];
            bool back = e == HS_WIDE_RETURN;
            bool node = (e & HS_LEAF_FLAG) == 0u && !back;
            over = node && top > HS_WIDE_STACK - 4;
            if (back) { inside = false; q_lo = t_lo; q_hi = t_hi; q_inv = t_inv; }
            if (node && !over) {
                int at = 2 * int(e);
                uvec4 c0 = HS_FETCH(hs_wide_tex, at);
                uvec4 c1 = HS_FETCH(hs_wide_tex, at + 1);
                uvec4 c2 = HS_FETCH(hs_wide_tex, at + 2);
                uvec4 c3 = HS_FETCH(hs_wide_tex, at + 3);
                // (c0 and c2 are the two binary children or their first children: always there)
                stack[top] = c3.w;
                top += (c3.w != 0u && hs_qbox_hit(q_lo, q_hi, q_inv, c3, tmax)) ? 1 : 0;
                stack[top] = c2.w;
                top += hs_qbox_hit(q_lo, q_hi, q_inv, c2, tmax) ? 1 : 0;
                stack[top] = c1.w;
                top += (c1.w != 0u && hs_qbox_hit(q_lo, q_hi, q_inv, c1, tmax)) ? 1 : 0;
                stack[top] = c0.w;
                top += hs_qbox_hit(q_lo, q_hi, q_inv, c0, tmax) ? 1 : 0;
            }
            found = !node && !back;
            walking = !found && !over && top > 0;
        }
        if (over) return hs_trace_binary(o, d, tmax);
        if (!found) break;
        found = top > 0;
        uint pay = e & 0x7FFFFFFFu;
#ifdef HS_LINKING
        if (!inside && !hs_link_blocks(int(pay))) continue;   // not the light's blocker: on
#endif
        int at = inside ? int(pay >> 3u) : 5 * int(pay);
        vec4 x0, x1, x2, x3, x4, x5, x6, x7, x8;
        uvec4 u3;
        hs_leaf_record(at, x0, x1, x2, u3, x3, x4, x5, x6, x7, x8);
        if (!inside) {
            vec3 m_o = hs_affine(x0, x1, x2, o);
            vec3 m_d = hs_linear(x0, x1, x2, d);
            bool is_sphere = (u3.z & HS_SPHERE_FLAG) != 0u;
#ifdef HS_HAS_SPHERES
            if (is_sphere && hs_sphere_hit(m_o, m_d, x4.xyz, x4.w, tmax)) return HS_BLOCKED;
#endif
#ifdef HS_HAS_MESHES
            if (!is_sphere && int(u3.y) > int(u3.x)) {
                if (top > HS_WIDE_STACK - 2) return hs_trace_binary(o, d, tmax);
                hs_model_ray(m_o, m_d, x4, q_lo, q_hi, q_inv);
                om = m_o;
                sh = hs_shear_setup(m_d);
                inside = true;
                stack[top++] = HS_WIDE_RETURN;
                stack[top++] = hs_wide_root(int(u3.x), int(u3.y));
                found = true;
#ifdef HS_HAS_ALPHA
                amat = int(u3.w);
                if (amat != 0) cut = hs_cut_setup(amat - 1);
#endif
            }
#endif
        }
#ifdef HS_HAS_MESHES
        else {
#ifdef HS_HAS_ALPHA
            vis *= hs_leaf_vis(om, sh, int(pay & 7u), x0, x1, x2, x3, x4, x5, x6, x7, x8, tmax, cut, amat != 0, at);
            if (vis < HS_VIS_MIN) return HS_BLOCKED;
#else
            if (hs_leaf_hit(om, sh, int(pay & 7u), x0, x1, x2, x3, x4, x5, x6, x7, x8, tmax)) return HS_BLOCKED;
#endif
        }
#endif
    }
    return HS_UNBLOCKED;
}
#else
HS_TRACE_T hs_trace(vec3 o, vec3 d, float tmax) { return hs_trace_binary(o, d, tmax); }
#endif

#ifdef HS_HAS_ALPHA
// Visibility in [0, 1]: the product of the transmittances of every alpha-cut surface the ray
// crosses in (0, tmax), 0 at an opaque one.
float hs_visibility(vec3 o, vec3 d, float tmax) { return hs_trace(o, d, tmax); }
bool hs_occluded(vec3 o, vec3 d, float tmax) { return hs_trace(o, d, tmax) == 0.0; }
#else
bool hs_occluded(vec3 o, vec3 d, float tmax) { return hs_trace(o, d, tmax); }
float hs_visibility(vec3 o, vec3 d, float tmax) { return hs_trace(o, d, tmax) ? 0.0 : 1.0; }
#endif

#ifdef HS_SOFT_PACKET
#include "common/scene_packet.glsl"
#endif

#endif // HS_SCENE_BVH_GLSL
