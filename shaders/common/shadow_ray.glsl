// The shadow ray of one G-buffer pixel towards one light, shared by raytrace.glsl (which traces
// it) and refine_classify.glsl (which decides whether the pixel needs it), so both see the very
// same surface point, normal and facing/reach tests. Needs common/camera.glsl, common/gbuffer.glsl.
// Defines: HS_LIGHT_SUN or HS_LIGHT_LOCAL, HS_MAX_DISTANCE, HS_SOFT (no facing test: an
// extended light's samples weigh the horizon themselves), HS_TERMINATOR (the scene has smooth-shaded
// models: the G-buffer's shading normal decides facing, their shadow terminator moves the
// origins, shadow_ray_origin; without it every normal is the geometric one).

uniform vec3 u_light_vec;       // sun: unit direction towards it; else the light's position
                                // (bake space: world - the bake's origin)
uniform vec3 u_cam_bake;        // camera position in bake space (float64 on the CPU)
#ifdef HS_LIGHT_LOCAL
uniform vec3 u_light_axis;      // unit direction the light shines towards
uniform float u_light_cone;     // no light where dot(light -> p, axis) <= this: a spot's
                                // cos(size / 2), 0 behind an area light, -2 (never) for a point
#endif
#ifdef HS_MAX_DISTANCE
uniform float u_max_distance;
#endif
#ifdef HS_SOFT
uniform float u_light_radius;   // a sphere light's radius (common/soft_light.glsl)
#endif

// Ray origin pushed off the surface along the normal, by the float32 error of p and of its
// transform into a model's space: a few ULPs of p's largest coordinate (an instance's rotation
// mixes the axes, so the error along n is that of the largest one), at least a small absolute
// step near the bake origin. Along n only: a push across the surface moves the point whose
// shadow is sampled (per-coordinate ULP pushes, Waechter & Binder's, do so far from the bake
// origin, where ULPs are large next to a close-up pixel). 'slack' adds the G-buffer
// reconstruction error, which grows with the distance from the camera.
vec3 offset_origin(vec3 p, vec3 n, float slack)
{
    const float ulps = 4.76837158203125e-07;   // 2^-21: 4 to 8 ULPs of the largest coordinate
    const float min_step = 1.0 / 65536.0;
    float m = max(max(abs(p.x), abs(p.y)), abs(p.z));
    precise vec3 o = p + n * (max(m * ulps, min_step) + slack);
    return o;
}

// The surface point of pixel px in bake space: the camera ray scaled to the G-buffer's view
// depth, added to the camera's bake-space position. Rebuilt camera-relative, it keeps float32
// precision wherever the scene sits in the world (100 km out as well as at the origin).
vec3 surface_point(ivec2 px, float depth)
{
    vec3 o_rel, dir;
    camera_ray_exact(vec2(px) + 0.5, o_rel, dir);
    precise vec3 p_rel = (u_ortho == 1) ? o_rel + dir * (depth - u_clip_start) : dir * (depth / u_clip_start);
    precise vec3 p = u_cam_bake + p_rel;
    return p;
}

// (The knife-edge values, the point, the facing and reach tests, the origin, are precise: the
// fragment and compute stages then decide them alike, as the numpy mirror does.)
//
// What pixel px gets without a ray: 1 (background, beyond the max distance), 0 (its shading
// normal faces away from the light, out of its reach), or -1: it needs a ray; p, n (geometric,
// towards the camera), ns (shading), depth and to_light are then set. Light arrives where the
// shading normal faces it, as a diffuse closure evaluates it in Cycles (closure/bsdf_diffuse.h:
// the geometric normal does not decide; a smooth surface is lit past its facets' terminator).
float shadow_ray_prelude(ivec2 px, out vec3 p, out vec3 n, out vec3 ns, out float depth, out vec3 to_light)
{
    p = vec3(0.0); n = vec3(0.0); ns = vec3(0.0); depth = 0.0; to_light = vec3(0.0);
    vec4 nw = texelFetch(u_gb_normal, px, 0);
    if (nw.w == 0.0) return 1.0;
    depth = texelFetch(u_gb_depth, px, 0).r;
    p = surface_point(px, depth);
#ifdef HS_MAX_DISTANCE
    if (distance(p, u_cam_bake) > u_max_distance) return 1.0;
#endif
    n = nw.xyz;
#ifdef HS_TERMINATOR
    ns = texelFetch(u_gb_shading, px, 0).xyz;
#else
    ns = n;                           // (flat models only: the G-buffer's shading normal is n)
#endif
#ifdef HS_LIGHT_LOCAL
    to_light = u_light_vec - p;
#else
    to_light = u_light_vec;
#endif
#ifndef HS_SOFT
    precise float facing = dot(ns, to_light);
    if (facing <= 0.0) return 0.0;    // faces away: unlit, no ray
#endif                                // (an extended light can be partly above the horizon)
#ifdef HS_LIGHT_LOCAL
    float reach = u_light_cone;
#if defined(HS_SOFT) && HS_SOFT_SHAPE == 1
    // a spot of radius r: its points reach a cone wider by the angle b the sphere subtends,
    // cos(half + b) (each point's own cone weighs its sample: common/soft_light.glsl)
    if (reach >= -1.0) {
        float sb = min(u_light_radius * inversesqrt(max(dot(to_light, to_light), 1e-30)), 1.0);
        reach = reach * sqrt(1.0 - sb * sb) - sqrt(max(1.0 - reach * reach, 0.0)) * sb;
    }
#endif
    precise float toward = dot(-normalize(to_light), u_light_axis);
    if (toward <= reach) return 0.0;  // out of reach
#endif
    return -1.0;
}

// The origin of pixel px's shadow ray towards to_light (p, n, ns, depth: shadow_ray_prelude's),
// as Cycles' shadow_ray_offset (light/sample.h) decides it. On a smooth-shaded triangle whose
// shading or geometric normal is within the object's geometry offset (cosine) of the
// terminator, the origin rises towards the smooth surface by a share of the G-buffer's lift
// (HS_TERMINATOR: gbuffer.glsl's TERMINATOR writes it). Cycles' ray skips its own triangle
// unless that lift applied while the geometric normal faces away from the light: the ray is then
// meant to be able to hit its own surface. Pushing the origin off the plane along n stands for
// the skip; the other case starts at the lifted point itself.
vec3 shadow_ray_origin(ivec2 px, vec3 p, vec3 n, vec3 ns, float depth, vec3 to_light)
{
#ifdef HS_TERMINATOR
    vec4 lift = texelFetch(u_gb_terminator, px, 0);
    float cutoff = lift.w;
    if (cutoff > 0.0) {
        // (an extended light: towards its centre, for all its samples; those below the shading
        // horizon, the only ones Cycles lifts from the far side, carry no light)
        vec3 l = normalize(to_light);
        float nl = dot(ns, l);
        float ngl = dot(n, l);
        float amount = nl < cutoff ? clamp(2.0 - (ngl + nl) / cutoff, 0.0, 1.0)
                                   : clamp(1.0 - ngl / cutoff, 0.0, 1.0);
        if (amount > 0.0) {
            precise vec3 lifted = p + lift.xyz * amount;
            p = lifted;
            if (!(ngl > 0.0)) return p;       // meant to be able to hit its own surface
        }
    }
#endif
    return offset_origin(p, n, depth * 3.0e-6);
}
