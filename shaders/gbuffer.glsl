// Pass 1: the G-buffer. One instanced, indexed draw per model (triangles), or per sphere-primitive
// batch (define SPHERE: a box proxy around the model's bounding sphere, ray/ellipsoid in the
// fragment shader).
//
// The world position is NOT the interpolated vertex position: each fragment intersects its
// pixel-centre camera ray with the triangle's plane (camera-relative float32), which matches
// Cycles' position pass to a few ULPs. The geometric normal is the triangle's plane; the shading
// normal interpolates the model's smooth corner normals (the face normal for flat faces). Both
// turn over together where the camera sees a triangle's back (its winding), as Cycles turns N and
// Ng of a back-facing hit: a shading normal wound against its face stays against it.
// TERMINATOR (models with smooth corner normals): a geometry shader hands each fragment its
// triangle's corners and corner normals, and the fragment writes the lift of Cycles'
// shadow_ray_smooth_surface_offset (light/sample.h) at its point, in the world, with the object's
// Shadow Terminator Geometry Offset (common/shadow_ray.glsl decides per light how much of it a
// shadow ray takes). Without it the target is zero: no lift, no offset.
//
// Depth test on a logarithmic depth of that exact position (gl_FragDepth = log(depth / near) /
// log(far / near)): the projection's hyperbolic depth in a 24-bit buffer resolves only ~6 cm at
// 10 m when clip_start is 1e-4 (surfaces 2 cm apart z-fought); the log depth resolves ~1e-6 of
// the distance for any clip range.
// TEXTURED (models with UVs shown with a textured material): in_uv per vertex, in_matid per
// instance (-1: none); the albedo is the colour image (mip mapped, common/alpha.glsl) times the
// instance colour, and fragments whose alpha the material cuts are discarded: at 0.5, or on
// sample u_alpha_sample of a see-through accumulation where a BLEND alpha is below the sample's
// hashed threshold (hs_alpha_keeps_sample).
#include "common/camera.glsl"
uniform float u_log_depth_scale;   // 1 / log2(clip_end / clip_start)

// The varyings, one list for the vertex, geometry and fragment stages (interface blocks: the
// geometry stage reads the vertex stage's block as an array and writes its own). Each macro is one
// line (GLSL 4.10 has no line continuation). v_plane_point: a point of the triangle (the
// provoking vertex), camera-relative; v_material: specular, roughness, instance index, terminator
// geometry offset; v_rel: the interpolated camera-relative position (fallback); v_shading: the
// interpolated world shading normal (unnormalised); v_face: the face normal in the world
// (unnormalised). HS_GB_TRIANGLE, the triangle a TERMINATOR fragment lies on: corner 0
// (camera-relative), the edges to corners 1 and 2, the three unit corner normals (world).
#ifdef SPHERE
#define HS_GB_SHAPE flat vec4 v_i0; flat vec4 v_i1; flat vec4 v_i2; flat vec4 v_sphere; flat vec3 v_n0; flat vec3 v_n1; flat vec3 v_n2;
#else
#define HS_GB_SHAPE flat vec3 v_face;
#endif
#ifdef TEXTURED
#define HS_GB_TEXTURE vec2 v_uv; flat int v_matid;
#else
#define HS_GB_TEXTURE
#endif
#define HS_GB_VARYINGS flat vec3 v_plane_point; flat vec4 v_color; flat vec4 v_material; vec3 v_rel; vec3 v_shading; HS_GB_SHAPE HS_GB_TEXTURE
#define HS_GB_TRIANGLE flat vec3 t_v0; flat vec3 t_e1; flat vec3 t_e2; flat vec3 t_n0; flat vec3 t_n1; flat vec3 t_n2;

#ifdef VERTEX_SHADER
layout(location = 0) in vec3 in_pos;          // model space (a triangle's last corner: its plane point)
layout(location = 2) in vec3 in_shading_normal;  // model space: smooth corner normal (zero: flat)
#ifndef SPHERE
in vec3 in_face_normal;        // model space unit face normal (read from the provoking corner)
#endif
// per instance
in vec4 in_m0; in vec4 in_m1; in vec4 in_m2;  // rows of the camera-relative world matrix
in vec3 in_n0; in vec3 in_n1; in vec3 in_n2;  // rows of the normal matrix (inverse transpose)
in vec4 in_color;
in vec4 in_material;                          // specular, roughness, instance index, terminator
#ifdef TEXTURED
in vec2 in_uv;
in float in_matid;
#endif
#ifdef SPHERE
in vec4 in_i0; in vec4 in_i1; in vec4 in_i2;  // rows of the inverse world matrix (camera-relative)
in vec4 in_sphere;                            // model-space bounding sphere: centre, radius
#endif

out VertexData { HS_GB_VARYINGS };

void main() {
    vec4 p = vec4(in_pos, 1.0);
#ifdef SPHERE
    p.xyz = in_sphere.xyz + in_pos * in_sphere.w;   // unit cube corners -> box around the sphere
    v_i0 = in_i0; v_i1 = in_i1; v_i2 = in_i2; v_sphere = in_sphere;
#endif
    vec3 rel = vec3(dot(in_m0, p), dot(in_m1, p), dot(in_m2, p));
    v_rel = rel;
    v_plane_point = rel;
    v_shading = vec3(dot(in_n0, in_shading_normal), dot(in_n1, in_shading_normal), dot(in_n2, in_shading_normal));
#ifdef SPHERE
    v_n0 = in_n0; v_n1 = in_n1; v_n2 = in_n2;
#else
    v_face = vec3(dot(in_n0, in_face_normal), dot(in_n1, in_face_normal), dot(in_n2, in_face_normal));
#endif
    v_color = in_color;
    v_material = in_material;
#ifdef TEXTURED
    v_uv = in_uv;
    v_matid = int(in_matid);
#endif
    gl_Position = u_clip_from_rel * vec4(rel, 1.0);
}
#endif

#if defined(GEOMETRY_SHADER) && defined(TERMINATOR)
// GEOMETRY_SHADER only with TERMINATOR (programs.py builds the stage only then)
layout(triangles) in;
layout(triangle_strip, max_vertices = 3) out;
in VertexData { HS_GB_VARYINGS } corner[];
out TriangleData { HS_GB_VARYINGS HS_GB_TRIANGLE };

vec3 unit_or_zero(vec3 v) { float l = length(v); return l > 0.0 ? v / l : vec3(0.0); }

void main() {
    vec3 n0 = unit_or_zero(corner[0].v_shading);
    vec3 n1 = unit_or_zero(corner[1].v_shading);
    vec3 n2 = unit_or_zero(corner[2].v_shading);
    for (int k = 0; k < 3; ++k) {
        gl_Position = gl_in[k].gl_Position;
        v_plane_point = corner[k].v_plane_point;
        v_color = corner[k].v_color;
        v_material = corner[k].v_material;
        v_rel = corner[k].v_rel;
        v_shading = corner[k].v_shading;
        v_face = corner[k].v_face;
#ifdef TEXTURED
        v_uv = corner[k].v_uv;
        v_matid = corner[k].v_matid;
#endif
        t_v0 = corner[0].v_rel;
        t_e1 = corner[1].v_rel - corner[0].v_rel;
        t_e2 = corner[2].v_rel - corner[0].v_rel;
        t_n0 = n0; t_n1 = n1; t_n2 = n2;
        EmitVertex();
    }
    EndPrimitive();
}
#endif

#ifdef FRAGMENT_SHADER
#ifdef TEXTURED
#include "common/alpha.glsl"
uniform int u_alpha_sample;   // see-through accumulation's sample index; -1: none (alpha >= 0.5)
#endif
#ifdef TERMINATOR
in TriangleData { HS_GB_VARYINGS HS_GB_TRIANGLE };

// Cycles' shadow_ray_smooth_surface_offset (light/sample.h) at camera-relative point p of the
// triangle, with ng its geometric normal turned towards the camera: the lift n * h towards the
// smooth surface its corner normals describe (a parabolic fit, bounded by the corners' tangent
// planes on the side the interpolated normal n lies), in the world.
vec3 smooth_surface_offset(vec3 p, vec3 ng) {
    vec3 d = p - t_v0;                       // (P - V0): the barycentrics of p
    float d00 = dot(t_e1, t_e1), d01 = dot(t_e1, t_e2), d11 = dot(t_e2, t_e2);
    float d20 = dot(d, t_e1), d21 = dot(d, t_e2);
    float den = d00 * d11 - d01 * d01;
    if (!(abs(den) > 0.0)) return vec3(0.0);
    float v = (d11 * d20 - d01 * d21) / den; // weight of corner 1
    float w = (d00 * d21 - d01 * d20) / den; // weight of corner 2
    float u = 1.0 - v - w;                   // weight of corner 0
    vec3 dp = v * t_e1 + w * t_e2;           // P - V0 on the plane
    vec3 n = t_n0 * u + t_n1 * v + t_n2 * w;
    float a = dot(t_n2 - t_n0, -t_e2);
    float b = dot(t_n2 - t_n1, t_e1 - t_e2);
    float c = dot(t_n1 - t_n0, t_e1);
    float h = a * u * (u - 1.0) + (a + b + c) * u * v + b * v * (v - 1.0);
    if (dot(n, ng) > 0.0) {
        float h0 = max(max(dot(t_e1, t_n0), dot(t_e2, t_n0)), 0.0);
        float h1 = max(max(dot(-t_e1, t_n1), dot(t_e2 - t_e1, t_n1)), 0.0);
        float h2 = max(max(dot(-t_e2, t_n2), dot(t_e1 - t_e2, t_n2)), 0.0);
        h0 = max(dot(-dp, t_n0) + h0, 0.0);
        h1 = max(dot(t_e1 - dp, t_n1) + h1, 0.0);
        h2 = max(dot(t_e2 - dp, t_n2) + h2, 0.0);
        h = max(min(min(h0, h1), h2), h * 0.5);
    } else {
        float h0 = max(max(dot(-t_e1, t_n0), dot(-t_e2, t_n0)), 0.0);
        float h1 = max(max(dot(t_e1, t_n1), dot(t_e1 - t_e2, t_n1)), 0.0);
        float h2 = max(max(dot(t_e2, t_n2), dot(t_e2 - t_e1, t_n2)), 0.0);
        h0 = max(dot(dp, t_n0) + h0, 0.0);
        h1 = max(dot(dp - t_e1, t_n1) + h1, 0.0);
        h2 = max(dot(dp - t_e2, t_n2) + h2, 0.0);
        h = min(-min(min(h0, h1), h2), h * 0.5);
    }
    return n * h;
}
#else
in VertexData { HS_GB_VARYINGS };
#endif

layout(location = 0) out vec4 o_position;   // world xyz, w = 1
layout(location = 1) out vec4 o_normal;     // geometric normal (unit, facing the camera), w = 1
layout(location = 2) out vec4 o_shading;    // shading normal (turned with the geometric one), w = 1
layout(location = 3) out vec4 o_albedo;     // linear base colour
layout(location = 4) out vec4 o_material;   // specular, roughness, instance index, 1
layout(location = 5) out vec4 o_depth;      // r: view depth (metres along the view axis)
layout(location = 6) out vec4 o_terminator; // xyz: the smooth-surface lift (world), w: geometry offset

// A holdout (instance index stored as -(index + 1), passes/gbuffer.py holdout_index): background
// to every pass (position, normals and depth zero: no shadow ray, no lighting), hiding what lies
// behind it through the depth test; material w = -1 tells the lighting to write a hole (alpha 0,
// no colour), as Cycles' holdout does in the film.
void write_holdout() {
    o_position = vec4(0.0);
    o_normal = vec4(0.0);
    o_shading = vec4(0.0);
    o_albedo = vec4(0.0);
    o_material = vec4(0.0, 0.0, -v_material.z - 1.0, -1.0);
    o_depth = vec4(0.0);
    o_terminator = vec4(0.0);
}

void main() {
    vec4 albedo = v_color;
#ifdef TEXTURED
    if (v_matid >= 0) {
        // the mip level from the screen-space footprint of the image's texels (derivatives
        // first: they need every lane of the quad)
        vec2 tex_size = hs_material_color_size(v_matid);
        vec2 tuv = hs_material_uv(v_matid, v_uv);
        vec2 dx = dFdx(tuv) * tex_size, dy = dFdy(tuv) * tex_size;
        float lod = 0.5 * log2(max(max(dot(dx, dx), dot(dy, dy)), 1e-30));
        if (!hs_alpha_keeps_sample(v_matid, v_uv, u_alpha_sample, uvec2(gl_FragCoord.xy),
                                   uint(v_material.z + 0.5))) discard;
        albedo.rgb *= hs_material_color(v_matid, v_uv, lod);
    }
#endif
    vec3 ro, rd;
    camera_ray(gl_FragCoord.xy, ro, rd);
    vec3 p;
    vec3 n;
#ifdef SPHERE
    // ray into model space, intersect the bounding sphere there (an ellipsoid in the world)
    vec3 mo = vec3(dot(v_i0, vec4(ro, 1.0)), dot(v_i1, vec4(ro, 1.0)), dot(v_i2, vec4(ro, 1.0)));
    vec3 md = vec3(dot(v_i0.xyz, rd), dot(v_i1.xyz, rd), dot(v_i2.xyz, rd));
    vec3 f = mo - v_sphere.xyz;
    float a = dot(md, md);
    float b = -dot(f, md) / a;                    // t of the closest approach
    vec3 perp = f + b * md;
    float r2 = v_sphere.w * v_sphere.w;
    float disc = r2 - dot(perp, perp);
    if (disc < 0.0) discard;
    float t = b - sqrt(disc / a);
    if (t < 0.0) t = b + sqrt(disc / a);         // camera inside the sphere
    if (t < 0.0) discard;
    p = ro + t * rd;
    vec3 nm = (mo + t * md) - v_sphere.xyz;
    n = vec3(dot(v_n0, nm), dot(v_n1, nm), dot(v_n2, nm));
    vec4 clip = u_clip_from_rel * vec4(p, 1.0);
    float zndc = clip.z / clip.w;
    if (zndc < -1.0 || zndc > 1.0) discard;
#else
    // the face normal, from the provoking corner (geometry.indexed_vertex_data), in the world
    n = v_face;
    float denom = dot(n, rd);
    p = v_rel;
    if (abs(denom) > 1e-12 * length(n) * length(rd)) {
        float t = dot(n, v_plane_point - ro) / denom;
        vec3 q = ro + t * rd;
        // keep the plane hit unless it is far off the rasterised point (grazing triangles)
        if (t > 0.0 && length(q - v_rel) < 1e-2 * length(v_rel) + 1e-6) p = q;
    }
#endif
    float len = length(n);
    n = len > 0.0 ? n / len : -normalize(rd);
    bool back = dot(n, rd) > 0.0;                // the camera sees the triangle's back:
    if (back) n = -n;                            // Cycles turns Ng and N towards it
#ifdef SPHERE
    vec3 ns = n;                                 // analytic: exact already
#else
    vec3 ns = v_shading;                         // smooth shading: interpolated corner normals
    float ls = length(ns);
    ns = ls > 0.0 ? (back ? -ns : ns) / ls : n;  // (none: the geometric normal)
#endif
#ifdef TERMINATOR
    o_terminator = vec4(smooth_surface_offset(p, n), v_material.w);
#else
    o_terminator = vec4(0.0);
#endif
    o_position = vec4(u_cam_pos + p, 1.0);
    o_normal = vec4(n, 1.0);
    o_shading = vec4(ns, 1.0);
    o_albedo = albedo;
    o_material = vec4(v_material.xyz, 1.0);
    float vd = view_depth(p);
    o_depth = vec4(vd, 0.0, 0.0, 1.0);
    gl_FragDepth = clamp(log2(max(vd, 1e-30) / u_clip_start) * u_log_depth_scale, 0.0, 1.0);
    if (v_material.z < 0.0) write_holdout();
}
#endif
