// Conservative light-space occupancy map (Hertel, Hormann & Westermann 2009): per texel a LOWER
// BOUND of the light depth of every shadow caster whose surface touches the texel's column
// (sun: an orthographic column along the light direction; point/spot: the pyramid through the
// light of one cube face). MIN blending into an R32F atlas tile; cleared to +1e30 ("empty").
//
// View coordinates v = (right, up, f): f = depth along the view's forward axis (away from the
// light), relative to u_origin. Standard coordinates s: sun s = v.xy (metres), cube face
// s = v.xy / v.z (in [-1, 1] on the face). The tile maps the window [u_win_lo, u_win_lo +
// u_tile_size / u_win_scale] of s onto u_tile_size^2 texels.
//
// Conservative by construction (see passes/conservative.py for the error budget):
// - coverage: each triangle emits the bounding box of its (near-clipped, projected) polygon,
//   grown by u_expand (world-position uncertainty; divided by the polygon's nearest depth for
//   perspective faces) plus half a texel plus 1/16 texel, so every texel whose column the
//   triangle touches has its centre strictly inside the quad;
// - depth: per texel the maximum of two lower bounds of the triangle's depth inside the column:
//   the polygon's smallest vertex depth, and the minimum of the triangle's plane over the
//   texel (sun: depth affine in s; face: 1/depth affine in s), padded for float error; planes
//   too ill-conditioned to bound reliably use the vertex bound only;
// - a perspective triangle reaching behind the near plane close to the light writes -1e30 to
//   the whole tile (culling off for that face).

#ifdef VERTEX_SHADER
layout(location = 0) in vec3 in_pos;
in vec4 in_m0; in vec4 in_m1; in vec4 in_m2;   // rows of the origin-relative world matrix
uniform mat3 u_basis;                          // columns: right, up, forward (world)
out vec3 g_v;
void main() {
    vec4 p = vec4(in_pos, 1.0);
    vec3 rel = vec3(dot(in_m0, p), dot(in_m1, p), dot(in_m2, p));
    g_v = rel * u_basis;                       // (dot(rel, right), dot(rel, up), dot(rel, fwd))
    gl_Position = vec4(0.0, 0.0, 0.0, 1.0);
}
#endif

#ifdef GEOMETRY_SHADER
layout(triangles) in;
layout(triangle_strip, max_vertices = 4) out;
in vec3 g_v[];
uniform int u_persp;
uniform float u_near;
uniform vec2 u_win_lo;
uniform vec2 u_win_scale;      // texels per standard unit, per axis
uniform float u_tile_size;
uniform float u_expand;        // world-position uncertainty (metres)
flat out vec4 f_a;             // sun: g.xy (depth gradient), a.xy ; face: n.xyz, k
flat out vec4 f_b;             // vmin, mode (0 vertex bound, 1 + plane, 2 force -1e30), a.z, 0

void emit_quad(vec2 tlo, vec2 thi) {
    tlo = clamp(tlo, vec2(-1.0), vec2(u_tile_size + 1.0));
    thi = clamp(thi, vec2(-1.0), vec2(u_tile_size + 1.0));
    vec2 nlo = tlo / u_tile_size * 2.0 - 1.0;
    vec2 nhi = thi / u_tile_size * 2.0 - 1.0;
    gl_Position = vec4(nlo.x, nlo.y, 0.0, 1.0); EmitVertex();
    gl_Position = vec4(nhi.x, nlo.y, 0.0, 1.0); EmitVertex();
    gl_Position = vec4(nlo.x, nhi.y, 0.0, 1.0); EmitVertex();
    gl_Position = vec4(nhi.x, nhi.y, 0.0, 1.0); EmitVertex();
    EndPrimitive();
}

void main() {
    vec3 a = g_v[0], b = g_v[1], c = g_v[2];
    vec2 lo = vec2(1e30), hi = vec2(-1e30);
    float vmin = 1e30;
    bool clipped = false;
    if (u_persp == 0) {
        lo = min(min(a.xy, b.xy), c.xy);
        hi = max(max(a.xy, b.xy), c.xy);
        vmin = min(min(a.z, b.z), c.z);
    } else {
        int count = 0;
        for (int e = 0; e < 3; ++e) {
            vec3 p = g_v[e];
            vec3 q = g_v[e == 2 ? 0 : e + 1];
            bool pin = p.z >= u_near, qin = q.z >= u_near;
            if (pin) {
                vec2 s = p.xy / p.z;
                lo = min(lo, s); hi = max(hi, s); vmin = min(vmin, p.z); ++count;
            } else {
                clipped = true;
            }
            if (pin != qin) {
                float w = (u_near - p.z) / (q.z - p.z);
                vec3 x = p + (q - p) * clamp(w, 0.0, 1.0);
                float z = max(x.z, u_near);
                vec2 s = x.xy / z;
                lo = min(lo, s); hi = max(hi, s); vmin = min(vmin, u_near); ++count;
            }
        }
        if (count == 0) return;
    }
    vec3 e1 = b - a, e2 = c - a;
    vec3 n = cross(e1, e2);
    float ln = length(n);
    float mode = (ln > 1e-2 * length(e1) * length(e2)) ? 1.0 : 0.0;
    if (u_persp == 0) {
        float n1 = abs(n.x) + abs(n.y) + abs(n.z);
        if (abs(n.z) < 1e-3 * n1) mode = 0.0;
        vec2 g = mode > 0.0 ? -n.xy / n.z : vec2(0.0);
        f_a = vec4(g, a.xy);
        f_b = vec4(vmin, mode, a.z, 0.0);
    } else {
        float k = dot(n, a);
        if (abs(k) < 0.1 * ln * length(a)) mode = 0.0;
        if (clipped && !(abs(k) > 4.0 * u_near * ln)) {
            // the part behind the near plane may pass next to the light: no bound for this face
            f_a = vec4(0.0); f_b = vec4(-1e30, 2.0, 0.0, 0.0);
            emit_quad(vec2(-1.0), vec2(u_tile_size + 1.0));
            return;
        }
        f_a = vec4(n, k);
        f_b = vec4(vmin, mode, 0.0, 0.0);
    }
    float ex = u_persp == 0 ? u_expand : u_expand / vmin;
    float pad = 0.5 + 1.0 / 16.0;
    vec2 tlo = (lo - ex - u_win_lo) * u_win_scale - pad;
    vec2 thi = (hi + ex - u_win_lo) * u_win_scale + pad;
    if (any(lessThan(thi, vec2(0.0))) || any(greaterThan(tlo, vec2(u_tile_size)))) return;
    emit_quad(tlo, thi);
}
#endif

#ifdef FRAGMENT_SHADER
uniform int u_persp;
uniform vec2 u_win_lo;
uniform vec2 u_win_scale;
uniform vec2 u_tile_origin;    // atlas texel of the tile's corner
flat in vec4 f_a;
flat in vec4 f_b;
layout(location = 0) out float o_depth;

void main() {
    float vmin = f_b.x;
    int mode = int(f_b.y);
    if (mode == 2) { o_depth = -1e30; return; }
    vec2 c = gl_FragCoord.xy - u_tile_origin;          // texel centre (x.5)
    vec2 sc = u_win_lo + c / u_win_scale;
    vec2 hs = 0.5 / u_win_scale;
    float d = vmin;
    if (mode == 1) {
        if (u_persp == 0) {
            vec2 g = f_a.xy;
            vec2 dist = abs(sc - f_a.zw);
            float g1 = abs(g.x) + abs(g.y);
            float centre = f_b.z + dot(g, sc - f_a.zw);
            float spread = abs(g.x) * hs.x + abs(g.y) * hs.y;
            float slack = 1e-3 * (1.0 + g1) * (1.0 + g1) * (dist.x + dist.y + hs.x + hs.y);
            d = max(d, centre - spread - slack);
        } else {
            vec3 n = f_a.xyz;
            float k = f_a.w;
            float numer = n.x * sc.x + n.y * sc.y + n.z;
            float spread = abs(n.x) * hs.x + abs(n.y) * hs.y;
            float err = 1e-4 * (abs(n.x) + abs(n.y) + abs(n.z)) * (1.0 + abs(sc.x) + abs(sc.y) + hs.x + hs.y);
            float inv_max = (k > 0.0 ? numer + spread + err : numer - spread - err) / k;
            if (inv_max > 0.0) d = max(d, (1.0 / inv_max) * (1.0 - 4e-3));
        }
    }
    o_depth = d;
}
#endif
