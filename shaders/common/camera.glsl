// Blender camera for full-screen and G-buffer passes. Positions on the GPU are camera-relative
// ("rel" = world - u_cam_pos, computed in float64 on the CPU) so float32 keeps full precision
// near the camera wherever the scene sits in the world.
uniform mat4 u_clip_from_rel;   // projection * rotation part of the view matrix
uniform mat3 u_cam_rot;         // camera axes in world space (columns: right, up, back)
uniform vec3 u_cam_pos;         // camera origin in world space
uniform vec4 u_viewplane;       // Blender's viewplane: xmin, xmax, ymin, ymax (at clip_start)
uniform vec2 u_resolution;      // render width, height in pixels
uniform float u_clip_start;
uniform int u_ortho;            // 1: orthographic

// The camera ray through window position `frag` (gl_FragCoord.xy: pixel centres at +0.5), in
// camera-relative world space, exactly as Camera.pixel_rays builds it (direction not normalised
// for perspective cameras).
void camera_ray(vec2 frag, out vec3 origin_rel, out vec3 dir) {
    vec2 f = frag / u_resolution;
    vec3 local = vec3(mix(u_viewplane.x, u_viewplane.y, f.x), mix(u_viewplane.z, u_viewplane.w, f.y), -u_clip_start);
    if (u_ortho == 1) {
        origin_rel = u_cam_rot * local;
        dir = -u_cam_rot[2];
    } else {
        origin_rel = vec3(0.0);
        dir = u_cam_rot * local;
    }
}

// camera_ray rounded alike in every stage (precise: no fused multiply-adds), for the points the
// shadow rays start from (shadow_ray.glsl): the fragment and compute stages then decide a
// knife-edge test at such a point the same way.
void camera_ray_exact(vec2 frag, out vec3 origin_rel, out vec3 dir) {
    precise vec2 f = frag / u_resolution;
    precise vec3 local = vec3(mix(u_viewplane.x, u_viewplane.y, f.x), mix(u_viewplane.z, u_viewplane.w, f.y),
                              -u_clip_start);
    precise vec3 r = u_cam_rot * local;
    origin_rel = u_ortho == 1 ? r : vec3(0.0);
    dir = u_ortho == 1 ? -u_cam_rot[2] : r;
}

// View-space depth (distance along the camera's forward axis) of a camera-relative point.
float view_depth(vec3 p_rel) { return -dot(p_rel, u_cam_rot[2]); }

// Unit vector from a world point towards the viewer.
vec3 view_vector(vec3 p_world) {
    if (u_ortho == 1) return u_cam_rot[2];
    return normalize(u_cam_pos - p_world);
}

// A pixel's footprint (metres) on a surface facing the camera at view depth `depth`.
float hs_footprint(float depth)
{
    float w = (u_viewplane.y - u_viewplane.x) / u_resolution.x;
    return u_ortho == 1 ? w : w * depth / u_clip_start;
}
