// Pass 1: the G-buffer. One instanced, indexed draw per model (triangles), or per sphere-primitive
// batch (define SPHERE: a box proxy around the model's bounding sphere, ray/ellipsoid in the
// fragment shader).
//
// The world position is NOT the interpolated vertex position: each fragment intersects its
// pixel-centre camera ray with the triangle's plane (camera-relative float32), which matches
// Cycles' position pass to a few ULPs. The geometric normal is the triangle's plane; the shading
// normal interpolates the model's smooth corner normals (the face normal for flat faces).
//
// Depth test on a logarithmic depth of that exact position (gl_FragDepth = log(depth / near) /
// log(far / near)): the projection's hyperbolic depth in a 24-bit buffer resolves only ~6 cm at
// 10 m when clip_start is 1e-4 (surfaces 2 cm apart z-fought); the log depth resolves ~1e-6 of
// the distance for any clip range.
// TEXTURED (models with UVs shown with a textured material): in_uv per vertex, in_matid per
// instance (-1: none); the albedo is the colour image (mip mapped, common/alpha.glsl) times the
// instance colour, and fragments whose alpha the material cuts are discarded.
#include "common/camera.glsl"
uniform float u_log_depth_scale;   // 1 / log2(clip_end / clip_start)

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
in vec3 in_material;                          // specular, roughness, instance index
#ifdef TEXTURED
in vec2 in_uv;
in float in_matid;
out vec2 v_uv;
flat out int v_matid;
#endif
#ifdef SPHERE
in vec4 in_i0; in vec4 in_i1; in vec4 in_i2;  // rows of the inverse world matrix (camera-relative)
in vec4 in_sphere;                            // model-space bounding sphere: centre, radius
flat out vec4 v_i0; flat out vec4 v_i1; flat out vec4 v_i2;
flat out vec4 v_sphere;
#endif

flat out vec3 v_plane_point;   // a point of the triangle (the provoking vertex), camera-relative
flat out vec4 v_color;
flat out vec3 v_material;
#ifdef SPHERE
flat out vec3 v_n0; flat out vec3 v_n1; flat out vec3 v_n2;
#else
flat out vec3 v_face;          // the triangle's face normal in the world (unnormalised)
#endif
out vec3 v_rel;                // interpolated camera-relative position (fallback)
out vec3 v_shading;            // interpolated world shading normal (unnormalised)

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

#ifdef FRAGMENT_SHADER
#ifdef TEXTURED
#include "common/alpha.glsl"
in vec2 v_uv;
flat in int v_matid;
#endif
flat in vec3 v_plane_point;
flat in vec4 v_color;
flat in vec3 v_material;
#ifdef SPHERE
flat in vec3 v_n0; flat in vec3 v_n1; flat in vec3 v_n2;
#else
flat in vec3 v_face;
#endif
in vec3 v_rel;
in vec3 v_shading;
#ifdef SPHERE
flat in vec4 v_i0; flat in vec4 v_i1; flat in vec4 v_i2;
flat in vec4 v_sphere;
#endif

layout(location = 0) out vec4 o_position;   // world xyz, w = 1
layout(location = 1) out vec4 o_normal;     // geometric normal (unit, facing the camera), w = 1
layout(location = 2) out vec4 o_shading;    // shading normal, w = 1
layout(location = 3) out vec4 o_albedo;     // linear base colour
layout(location = 4) out vec4 o_material;   // specular, roughness, instance index, 1
layout(location = 5) out vec4 o_depth;      // r: view depth (metres along the view axis)

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
        if (!hs_alpha_keeps(v_matid, v_uv)) discard;
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
    if (dot(n, rd) > 0.0) n = -n;                // face the camera (Cycles flips back faces)
#ifdef SPHERE
    vec3 ns = n;                                 // analytic: exact already
#else
    vec3 ns = v_shading;                         // smooth shading: interpolated corner normals
    float ls = length(ns);
    ns = ls > 0.0 ? ns / ls : n;
    if (dot(ns, n) < 0.0) ns = -ns;              // on the geometric normal's side
#endif
    o_position = vec4(u_cam_pos + p, 1.0);
    o_normal = vec4(n, 1.0);
    o_shading = vec4(ns, 1.0);
    o_albedo = albedo;
    o_material = vec4(v_material, 1.0);
    float vd = view_depth(p);
    o_depth = vec4(vd, 0.0, 0.0, 1.0);
    gl_FragDepth = clamp(log2(max(vd, 1e-30) / u_clip_start) * u_log_depth_scale, 0.0, 1.0);
}
#endif
