/* scene_packet.glsl -- one walk for a pixel's soft-shadow rays (HS_SOFT_PACKET), included by
 * scene_bvh.glsl: the two-level BVH of that file walked once by the cone that bounds up to
 * HS_PACKET rays from one origin, each leaf's triangles tested against every ray of the packet.
 *
 * A pixel's rays towards an extended light share their origin and differ little in direction;
 * traced one by one, each walks nearly the same nodes and fetches nearly the same leaves. Walked
 * together, a node is fetched once and its box is tested against the cone around the rays; a
 * triangle is fetched once, its three edge planes through the origin (A x B, B x C, C x A) set
 * up once, and each ray then costs three dot products: the sign test of Benthin et al.'s
 * shared-origin packets, watertight as the single-ray test (an edge shared by two triangles
 * gives the same plane with the opposite sign, computed without contraction: 'precise'). The
 * planes are set up in the instance's model space and turned into bake space (L^T n, L the
 * instance's inverse world matrix), so the rays never move into model space. Measured on
 * soft_lights: a 28-ray packet visits 6-8x fewer nodes than its rays one by one; a triangle that
 * no ray of the cone can hit (the cone beyond one of its edge planes) takes no ray test.
 *
 * llvmpipe counts the iterations of all the loops of a shader invocation against one budget of
 * 65535, after which every loop stops (rays left untested, answers that look plausible): the
 * walk's loops and the rays of a triangle, four to an iteration, stay well within it for 64
 * rays on forest (soft.py's CHUNK_RAYS caps the rays of one draw; HS_LOOP_CHECK tests it).
 *
 * Cone: apex o, unit axis a, every ray within the angle whose sine is sin_a of a, and no ray
 * point further than len from the apex. A point p of a ray with |p - o| <= D projects onto the
 * axis at t in [0, D], less than D sin_a from p: a box holds such a point only when the axis
 * segment [0, D] meets the box widened by D sin_a, D the distance of the box's farthest corner
 * (at most len). The test is conservative by construction: it may walk a node no ray reaches,
 * never skip one a ray does. Packets whose rays spread wider than HS_PACKET_MIN_COS (a large
 * light close to the surface) are traced ray by ray.
 *
 * A rectangle or elongated ellipse light (HS_PACKET_PLANES, trace.py's pyramid_bounds)
 * bounds its rays tighter still: every ray lies inside the pyramid from the origin over the
 * light's rectangle, so a node wholly outside one of its four planes is skipped as well (the
 * planes go into each instance's model space as L^-T n). A cone around a rectangle sweeps a
 * circle about it, twice the rectangle's area at 2:1: clusters' 6 x 3 m light walks 41 % less
 * time (BENCHMARKS.md "The pyramid over an area light").
 *
 * Inputs: hs_pk_d[k], hs_pk_t[k] (the rays o + t d, t in (0, tmax), as hs_occluded takes them),
 * k < cnt, live: bit k set for the rays to trace. Result: bit k set where ray k is blocked;
 * with HS_HAS_ALPHA also hs_pk_vis[k], the light ray k keeps through the alpha-cut surfaces it
 * crosses (the product of their transmittances, as hs_visibility's; 0 where blocked). Mirror of
 * each ray's answer: hs_visibility (the same rays, equal but for rays that graze an edge or the
 * receiver's own surface within float32 error).
 */
#ifndef HS_SCENE_PACKET_GLSL
#define HS_SCENE_PACKET_GLSL

#define HS_PACKET 64
#define HS_PACKET_MIN_COS 0.5

vec3 hs_pk_d[HS_PACKET];    // the rays (bake space), set by the caller
float hs_pk_t[HS_PACKET];
vec4 hs_pk_ul[HS_PACKET];   // their unit directions (bake space) and lengths (one array: llvmpipe
                            // pays each access by a variable index in proportion to the array)
int hs_pk_cnt;              // rays in the packet
#ifdef HS_HAS_ALPHA
float hs_pk_vis[HS_PACKET]; // the light each ray keeps (the result, with the blocked bits)
bool hs_pk_cuts;            // the current instance cuts its shadow (hs_pk_cut), its leaf at
HsCut hs_pk_cut;            // [leaf] texel hs_pk_at
int hs_pk_at;
#endif

// ray masks: bit k of (x: rays 0..31, y: rays 32..63)
uvec2 hs_bit(int k) { uint b = 1u << uint(k & 31); return k < 32 ? uvec2(b, 0u) : uvec2(0u, b); }
bool hs_has(uvec2 m, int k) { return (((k < 32 ? m.x : m.y) >> uint(k & 31)) & 1u) != 0u; }
bool hs_none(uvec2 m) { return (m.x | m.y) == 0u; }

struct HsCone {
    vec3 apex; vec3 inv; float sin_a; float len; float e;   // (inv: 1 / axis)
#ifdef HS_PACKET_PLANES
    vec3 p0, p1, p2, p3;   // inward normals of the four planes through the apex that bound the rays
#endif
};

#ifdef HS_PACKET_PLANES
// The pyramid from o over the rectangle u_light_vec +- u_light_u +- u_light_v (an ellipse lies
// inside it), widened by 0.1 %: every ray of the packet lies inside its four planes through o
// (normals pointing inwards, bake space; set by the caller with hs_pk_set_pyramid)
vec3 hs_pk_pyr[4];
void hs_pk_set_pyramid(vec3 o, vec3 c, vec3 u, vec3 v)
{
    vec3 m = c - o, uw = 1.001 * u, vw = 1.001 * v;
    vec3 q0 = m - uw - vw, q1 = m + uw - vw, q2 = m + uw + vw, q3 = m - uw + vw;
    vec3 n0 = cross(q0, q1), n1 = cross(q1, q2), n2 = cross(q2, q3), n3 = cross(q3, q0);
    hs_pk_pyr[0] = dot(n0, m) < 0.0 ? -n0 : n0;
    hs_pk_pyr[1] = dot(n1, m) < 0.0 ? -n1 : n1;
    hs_pk_pyr[2] = dot(n2, m) < 0.0 ? -n2 : n2;
    hs_pk_pyr[3] = dot(n3, m) < 0.0 ? -n3 : n3;
}

// Is the box [lo, hi] (widened by e) wholly outside the plane through the apex with inward
// normal pn? (its corner furthest along pn behind the plane, with a margin for float error)
bool hs_plane_out(vec3 pn, vec3 lo, vec3 hi, vec3 apex, float e)
{
    vec3 pv = mix(lo, hi, step(0.0, pn)) - apex;
    vec3 an = abs(pn);
    return dot(pn, pv) < -(e * ((an.x + an.y) + an.z) + 1.0e-4 * dot(an, abs(pv)));
}
#endif

// sine bound of the cone from the largest sine s of a ray's angle to the axis (s from cross
// products: exact for narrow cones, where 1 - cos^2 is not)
float hs_cone_sin(float s) { return s * 1.0001 + 1.0e-6; }

// Does any ray of cone c reach the quantised node n (box widened by c.e, as the single ray's)?
bool hs_cone_box_hit(HsCone c, uvec4 n)
{
    vec3 blo = hs_qlo(n);
    vec3 bhi = hs_qhi(n);
    vec3 far = max(abs(blo - c.apex), abs(bhi - c.apex));
    float D = min(length(far) * 1.0001 + c.e, c.len);
    float rho = c.e + D * c.sin_a;
    vec3 t1 = (blo - vec3(rho) - c.apex) * c.inv;
    vec3 t2 = (bhi + vec3(rho) - c.apex) * c.inv;
    vec3 tn3 = min(t1, t2), tf3 = max(t1, t2);
    float tn = max(max(tn3.x, tn3.y), tn3.z);
    float tf = min(min(tf3.x, tf3.y), tf3.z) * HS_TFAR_SCALE;
#ifdef HS_PACKET_PLANES
    if (hs_plane_out(c.p0, blo, bhi, c.apex, c.e) || hs_plane_out(c.p1, blo, bhi, c.apex, c.e)
        || hs_plane_out(c.p2, blo, bhi, c.apex, c.e) || hs_plane_out(c.p3, blo, bhi, c.apex, c.e)) return false;
#endif
    return max(tn, 0.0) <= min(tf, D);
}

#ifdef HS_HAS_MESHES
// the current instance: rows of its linear map L (bake space -> model space) and the columns of
// its inverse; the bake-space cone's axis, sine bound and length
vec3 hs_pk_r0, hs_pk_r1, hs_pk_r2;
vec3 hs_pk_i0, hs_pk_i1, hs_pk_i2;   // the columns of L^-1
vec3 hs_pk_ax;
float hs_pk_sin, hs_pk_len;

vec3 hs_pk_back(vec3 a) { return (a.x * hs_pk_i0 + a.y * hs_pk_i1) + a.z * hs_pk_i2; }
// L^-T n: a bake-space plane normal in model space (the products with the columns of L^-1)
vec3 hs_pk_normal(vec3 n) { return vec3(dot(hs_pk_i0, n), dot(hs_pk_i1, n), dot(hs_pk_i2, n)); }

float hs_amax(vec3 v) { vec3 a = abs(v); return max(max(a.x, a.y), a.z); }

// The rays among 'need' (bake space: origin o, unit directions hs_pk_u, lengths hs_pk_l) that
// hit triangle v0 v1 v2 (model space, om = o in model space) at t in (floor, length). The edge
// planes through the origin are set up in model space (A x B, ...) and turned into bake space
// once per triangle (L^T n: a ray's product d . L^T n is its model-space direction's, L d . n,
// so t = T / det is the bake-space distance); no ray is moved into model space. A triangle that
// no ray of the cone can hit takes no ray test (on soft_lights, 1 in 2 to 7 of those tested has
// a hit). With HS_HAS_ALPHA, where the instance cuts its shadow, a hit multiplies the ray's
// hs_pk_vis by the transmittance at its UV (triangle ti of the leaf; the barycentrics are the
// edge products over det, as hs_tri_hit_b's) and blocks it only below HS_VIS_MIN.
uvec2 hs_pk_tri(vec3 om, uvec2 need, vec3 v0, vec3 v1, vec3 v2, int ti)
{
    precise vec3 A = v0 - om;
    precise vec3 B = v1 - om;
    precise vec3 C = v2 - om;
    precise vec3 nab = vec3(A.y * B.z - A.z * B.y, A.z * B.x - A.x * B.z, A.x * B.y - A.y * B.x);
    precise vec3 nbc = vec3(B.y * C.z - B.z * C.y, B.z * C.x - B.x * C.z, B.x * C.y - B.y * C.x);
    precise vec3 nca = vec3(C.y * A.z - C.z * A.y, C.z * A.x - C.x * A.z, C.x * A.y - C.y * A.x);
    precise float T = (A.x * nbc.x + A.y * nbc.y) + A.z * nbc.z;   // t = T / det
    // L^T n, with the sign of T (an exact flip: a hit then has all three products >= 0 and
    // det = their sum > 0; a shared edge's plane is still the other triangle's negated)
    float sg = T > 0.0 ? 1.0 : -1.0;
    precise vec3 pbc = sg * ((nbc.x * hs_pk_r0 + nbc.y * hs_pk_r1) + nbc.z * hs_pk_r2);
    precise vec3 pca = sg * ((nca.x * hs_pk_r0 + nca.y * hs_pk_r1) + nca.z * hs_pk_r2);
    precise vec3 pab = sg * ((nab.x * hs_pk_r0 + nab.y * hs_pk_r1) + nab.z * hs_pk_r2);
    float aT = abs(T);
    // no ray hits when the whole cone lies on the outer side of one edge's plane, or the plane
    // lies beyond every ray's length
    {
        float sa = hs_pk_sin;
        vec3 ax = hs_pk_ax;
        bool apart = dot(ax, pbc) < -sa * length(pbc) || dot(ax, pca) < -sa * length(pca)
                  || dot(ax, pab) < -sa * length(pab);
        if (T == 0.0 || apart || aT > 1.0001 * hs_pk_len * length(pab + pbc + pca)) need = uvec2(0u);
    }
    // hits nearer than the float32 error of T are the receiver's own surface (as hs_tri_hit_b:
    // HS_TFLOOR x the vertices' reach, here in bake space, L^-1 A)
    float fl = HS_TFLOOR * max(max(hs_amax(hs_pk_back(A)), hs_amax(hs_pk_back(B))), hs_amax(hs_pk_back(C)));
    uvec2 hit = uvec2(0u);
    // (only the span of rays still needed, the lowest to the highest bit of need: raytrace.glsl
    // orders a packet's rays in bands across the light, so once a caster's edge has blocked
    // the rays of one side the span is shorter; forest's sun 8 % less time)
    int klo = need.x != 0u ? findLSB(need.x) : 32 + findLSB(need.y);
    int nk = hs_none(need) ? 0 : (need.y != 0u ? 33 + findMSB(need.y) : 1 + findMSB(need.x));
    for (int k4 = klo & ~3; k4 < nk; k4 += 4) {   // (4 rays an iteration: llvmpipe's loop budget, above)
        for (int q = 0; q < 4; ++q) {
            int k = k4 + q;
            vec4 ul = hs_pk_ul[k];
            vec3 d = ul.xyz;
            precise float e0 = (d.x * pbc.x + d.y * pbc.y) + d.z * pbc.z;
            precise float e1 = (d.x * pca.x + d.y * pca.y) + d.z * pca.z;
            precise float e2 = (d.x * pab.x + d.y * pab.y) + d.z * pab.z;
            precise float det = (e0 + e1) + e2;
            bool h = min(min(e0, e1), e2) >= 0.0 && aT > fl * det && aT < ul.w * det;
#ifdef HS_HAS_ALPHA
            if (h && hs_pk_cuts && hs_has(need, k)) {
                hs_pk_vis[k] *= hs_cut_tri(hs_pk_cut, hs_pk_at, ti, vec3(e0, e1, e2) / det);
                h = hs_pk_vis[k] < HS_VIS_MIN;
            }
#endif
            if (h) hit |= hs_bit(k);
        }
    }
    return hit & need;
}
#endif

// hs_walk for the packet's cone (common/scene_bvh.glsl)
bool hs_pk_walk(inout int i, inout uint w, int limit, HsCone c)
{
    bool found = false;
    bool walking = i < limit;
    while (walking) {
        uvec4 n = HS_FETCH(hs_node_tex, i);
        bool leaf = (n.w & HS_LEAF_FLAG) != 0u;
        bool hit = hs_cone_box_hit(c, n);
        found = hit && leaf;
        w = n.w;
        i = (hit || leaf) ? i + 1 : int(n.w);   // (a leaf found: i is the node after it)
        walking = !found && i < limit;
    }
    return found;
}

// Bit k set: ray k of the packet (live bit k) is blocked (masks: hs_bit).
uvec2 hs_trace_packet(vec3 o, int cnt, uvec2 live)
{
    hs_pk_cnt = cnt;
    vec3 s = vec3(0.0);
    float len = 0.0;
    for (int k = 0; k < cnt; ++k) {
        float l = length(hs_pk_d[k]);
        bool on = hs_has(live, k) && l > 0.0 && hs_pk_t[k] > 0.0;
        if (!on) live &= ~hs_bit(k);
        vec3 u = on ? hs_pk_d[k] / l : vec3(0.0);
        float lk = on ? min(l * min(hs_pk_t[k], HS_FLT_BIG), 1.0e30) : 0.0;
        hs_pk_ul[k] = vec4(u, lk);
#ifdef HS_HAS_ALPHA
        hs_pk_vis[k] = 1.0;
#endif
        s += u;
        len = max(len, lk);
    }
    vec3 ax = normalize(s);
    float cmin = 1.0, smax = 0.0;
    for (int k = 0; k < cnt; ++k) {
        if (hs_has(live, k)) {
            vec3 u = hs_pk_ul[k].xyz;
            cmin = min(cmin, dot(u, ax));
            smax = max(smax, length(cross(u, ax)));
        }
    }
    uvec2 occ = uvec2(0u);
    bool going = !hs_none(live);   // (no return or break inside the loops: the walk ends by this flag)
    if (going && !(cmin > HS_PACKET_MIN_COS)) {   // too wide a spread to bound: ray by ray
        for (int k = 0; k < cnt; ++k) {
#ifdef HS_HAS_ALPHA
            if (hs_has(live, k)) {
                hs_pk_vis[k] = hs_visibility(o, hs_pk_d[k], hs_pk_t[k]);
                if (hs_pk_vis[k] == 0.0) occ |= hs_bit(k);
            }
#else
            if (hs_has(live, k) && hs_occluded(o, hs_pk_d[k], hs_pk_t[k])) occ |= hs_bit(k);
#endif
        }
        going = false;
    }
    HsCone tc;
    precise vec3 toq = (o - hs_tlas_base) * hs_tlas_inv_scale;
    vec3 ta = abs(toq);
    precise float te = HS_TLAS_EPS * (((ta.x + ta.y) + ta.z) + hs_tlas_babs);
    tc.apex = toq;
    tc.inv = hs_slab_inv(ax);
    tc.sin_a = hs_cone_sin(smax);
    tc.len = len * hs_tlas_inv_scale;
    tc.e = te;
#ifdef HS_PACKET_PLANES
    // (top-level boxes are bake space scaled by a power of two and moved: the same normals)
    tc.p0 = hs_pk_pyr[0]; tc.p1 = hs_pk_pyr[1]; tc.p2 = hs_pk_pyr[2]; tc.p3 = hs_pk_pyr[3];
#endif
    HsCone c = tc;
#ifdef HS_HAS_MESHES
    hs_pk_ax = ax;
    hs_pk_sin = tc.sin_a;
    hs_pk_len = len;
#endif
    int i = hs_tlas_root;
    int ret = -1;   // >= 0: inside a model tree, resume the top level there
    int limit = hs_tlas_end;   // the end of the tree being walked (the top level's, or the model tree's)
#ifdef HS_HAS_MESHES
    vec3 om = vec3(0.0);
#endif
#ifdef HS_HAS_ALPHA
    hs_pk_cuts = false;
    hs_pk_cut = hs_cut_setup(0);
    hs_pk_at = 0;
#endif
    while (going) {
        // (as hs_trace's walk: no branch in the node loop, the return to the top level here)
        uint w = 0u;
        bool found = hs_pk_walk(i, w, limit, c);
        if (!found && ret >= 0) {
            i = ret; ret = -1; c = tc; limit = hs_tlas_end;
            found = hs_pk_walk(i, w, limit, c);
        }
        if (!found) {
            going = false;
        } else {
            uint pay = w & 0x7FFFFFFFu;
            int next = i;
            int at = ret < 0 ? 5 * int(pay) : int(pay >> 3u);
            vec4 x0, x1, x2, x3, x4, x5, x6, x7, x8;
            uvec4 u3;
            hs_leaf_record(at, x0, x1, x2, u3, x3, x4, x5, x6, x7, x8);
            if (ret < 0) {
#ifdef HS_LINKING
              if (hs_link_blocks(int(pay))) {   // (not the light's blocker: on to the next node)
#endif
                // an instance: the cone in model space, from the bake-space one: the linear map L
                // (rows x0..x2) turns an angle of sine s about the axis into one of sine <= s
                // sigma_max / sigma_min (Gershgorin bounds of L^T L's eigenvalues), which stays below
                // 90 degrees while kappa^2 tan < 1 (else, a strong shear: every node of the model);
                // lengths grow by sigma_max at most
                vec3 m_o = hs_affine(x0, x1, x2, o);
                vec3 l0 = vec3(x0.x, x1.x, x2.x), l1 = vec3(x0.y, x1.y, x2.y), l2 = vec3(x0.z, x1.z, x2.z);
                float g01 = abs(dot(l0, l1)), g02 = abs(dot(l0, l2)), g12 = abs(dot(l1, l2));
                float ghi = 1.0001 * max(max(dot(l0, l0) + g01 + g02, dot(l1, l1) + g01 + g12), dot(l2, l2) + g02 + g12);
                float glo = 0.9999 * min(min(dot(l0, l0) - g01 - g02, dot(l1, l1) - g01 - g12), dot(l2, l2) - g02 - g12);
                float ml = len * sqrt(ghi);
                bool is_sphere = (u3.z & HS_SPHERE_FLAG) != 0u;
#ifdef HS_HAS_SPHERES
                if (is_sphere) {
                    for (int k = 0; k < cnt; ++k) {
                        vec4 ul = hs_pk_ul[k];
                        vec3 u = ul.xyz;
                        vec3 md = vec3(dot(x0.xyz, u), dot(x1.xyz, u), dot(x2.xyz, u));
                        if (hs_has(live, k) && hs_sphere_hit(m_o, md, x4.xyz, x4.w, ul.w)) occ |= hs_bit(k);
                    }
                    if (all(equal(occ & live, live))) next = hs_tlas_end;   // (all blocked: the walk ends)
                }
#endif
#ifdef HS_HAS_MESHES
                if (!is_sphere) {
                    float kap2 = glo > 0.0 ? ghi / glo : 1.0e30;
                    float ws = tc.sin_a;
                    bool narrow = kap2 * ws < 0.7 * sqrt(max(1.0 - ws * ws, 0.0));
                    vec3 mx = normalize(vec3(dot(x0.xyz, ax), dot(x1.xyz, ax), dot(x2.xyz, ax)));
                    om = m_o;
                    hs_pk_r0 = x0.xyz; hs_pk_r1 = x1.xyz; hs_pk_r2 = x2.xyz;
                    vec3 c0 = cross(x1.xyz, x2.xyz), c1 = cross(x2.xyz, x0.xyz), c2 = cross(x0.xyz, x1.xyz);
                    float ldet = dot(x0.xyz, c0);
                    hs_pk_i0 = c0 / ldet; hs_pk_i1 = c1 / ldet; hs_pk_i2 = c2 / ldet;
                    precise vec3 oq = (m_o - x4.xyz) * x4.w;
                    vec3 aq = abs(oq);
                    precise float e = HS_QEPS * ((aq.x + aq.y) + aq.z);
                    c.apex = oq;
                    c.inv = hs_slab_inv(mx);
                    c.sin_a = narrow ? hs_cone_sin(sqrt(kap2) * ws) : 1.0e30;
                    c.len = ml * x4.w;
                    c.e = e;
#ifdef HS_PACKET_PLANES
                    // a plane n.(x - o) >= 0 in bake space is (L^-T n).(m - m_o) >= 0 in model
                    // space (hs_pk_normal), and the same in the model's quantised space (scaled
                    // by a positive factor and moved). Also where the cone is lost to a strong
                    // shear (not narrow), as long as L^-1 is exact enough for the planes'
                    // margin (kappa < 100); beyond, none (zero normals)
                    bool planes = kap2 < 1.0e4;
                    c.p0 = planes ? hs_pk_normal(hs_pk_pyr[0]) : vec3(0.0);
                    c.p1 = planes ? hs_pk_normal(hs_pk_pyr[1]) : vec3(0.0);
                    c.p2 = planes ? hs_pk_normal(hs_pk_pyr[2]) : vec3(0.0);
                    c.p3 = planes ? hs_pk_normal(hs_pk_pyr[3]) : vec3(0.0);
#endif
                    ret = next;
                    next = int(u3.x);
                    limit = int(u3.y);
#ifdef HS_HAS_ALPHA
                    hs_pk_cuts = u3.w != 0u;
                    if (hs_pk_cuts) hs_pk_cut = hs_cut_setup(int(u3.w) - 1);
#endif
                }
#endif
#ifdef HS_LINKING
              }
#endif
            }
#ifdef HS_HAS_MESHES
            else {
                int tc_n = int(pay & 7u);
#ifdef HS_HAS_ALPHA
                hs_pk_at = at;
#endif
                occ |= hs_pk_tri(om, live & ~occ, x0.xyz, vec3(x0.w, x1.xy), vec3(x1.zw, x2.x), 0);
#if HS_BVH_LEAF_SIZE > 1
                if (tc_n > 1) occ |= hs_pk_tri(om, live & ~occ, x2.yzw, x3.xyz, vec3(x3.w, x4.xy), 1);
#endif
#if HS_BVH_LEAF_SIZE > 2
                if (tc_n > 2) occ |= hs_pk_tri(om, live & ~occ, vec3(x4.zw, x5.x), x5.yzw, x6.xyz, 2);
#endif
#if HS_BVH_LEAF_SIZE > 3
                if (tc_n > 3) occ |= hs_pk_tri(om, live & ~occ, vec3(x6.w, x7.xy), vec3(x7.zw, x8.x), x8.yzw, 3);
#endif
                if (all(equal(occ, live))) { next = hs_tlas_end; ret = -1; limit = hs_tlas_end; }   // (all blocked: the walk ends)
            }
#endif
            i = next;
        }
    }
    return occ & live;
}

#endif // HS_SCENE_PACKET_GLSL
