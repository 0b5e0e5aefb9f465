/* soft_light.glsl -- points on an extended light for soft shadows (HS_SOFT), included by
 * raytrace.glsl after common/shadow_ray.glsl. Mirror: hybrid_shadow_addon/core/oracle/soft.py.
 *
 * HS_SOFT_SHAPE: 0 a sun of angular diameter a (directions through a disk of radius tan(a/2)
 * in the plane across the sun's direction, as Cycles samples a distant light), 1 a sphere light
 * of radius r (point and spot lights with a radius: directions uniform in the cone it subtends),
 * 2 a rectangle, 3 an ellipse (area lights: points uniform on the surface; a spread below 180°
 * weighs each point by Cycles' soft-box attenuation of the direction towards the receiver).
 *
 * Each sample k of a pixel is a 2D point of the R2 sequence (Roberts 2018) shifted by a per-pixel,
 * per-light hash (Cranley-Patterson rotation): well spread within a pixel, decorrelated between
 * pixels, and a frame that continues at u_sample_base carries on the same sequence. A sample's
 * weight is what Cycles weights that point of the light by in the unshadowed irradiance
 * (receiver cosine; an area light's cosine and 1/r^2 as well), so the mask is the weighted
 * fraction of the light visible: sum(w v) / sum(w).
 */
#ifndef HS_SOFT_LIGHT_GLSL
#define HS_SOFT_LIGHT_GLSL

uniform int u_samples;        // rays per pixel (>= 1)
uniform int u_sample_base;    // index of this frame's first sample in each pixel's sequence
uniform uint u_seed;          // per light
uniform vec3 u_light_u;       // sun: tangent axis x tan(angle / 2); area: half-extent axes
uniform vec3 u_light_v;
uniform float u_light_radius; // sphere light radius
uniform vec2 u_light_spread;  // area light: (tan of the half spread, its normalisation); x < 0: none

#define HS_PROBES 4           // rays per pixel of the probe pass (HS_SOFT_PROBE)
#define HS_PROBE_RADIUS 2     // a pixel takes its probe answer when every probe within this
                              // many pixels saw all or none of the light alike

uint hs_hash(uvec3 v)
{
    // pcg3d (Jarzynski & Olano 2020), first component
    v = v * 1664525u + 1013904223u;
    v.x += v.y * v.z; v.y += v.z * v.x; v.z += v.x * v.y;
    v ^= v >> 16u;
    v.x += v.y * v.z; v.y += v.z * v.x; v.z += v.x * v.y;
    return v.x;
}

vec2 hs_sample2(ivec2 px, int k)
{
    uint h = hs_hash(uvec3(uvec2(px), u_seed));
    uint h2 = hs_hash(uvec3(h, 0x9E3779B9u, u_seed));
    vec2 rot = vec2(float(h >> 8u), float(h2 >> 8u)) * (1.0 / 16777216.0);
    return fract(rot + float(k) * vec2(0.7548776662466927, 0.5698402909980532));
}

// Shirley-Chiu concentric map of the unit square onto the unit disk
vec2 hs_concentric(vec2 u)
{
    vec2 a = 2.0 * u - 1.0;
    if (a.x == 0.0 && a.y == 0.0) return vec2(0.0);
    float r, phi;
    if (abs(a.x) > abs(a.y)) { r = a.x; phi = 0.7853981633974483 * (a.y / a.x); }
    else { r = a.y; phi = 1.5707963267948966 - 0.7853981633974483 * (a.x / a.y); }
    return r * vec2(cos(phi), sin(phi));
}

// Sample xi of the light seen from o (normal n): the ray o + t d, t in (0, tmax), and its weight.
void hs_light_sample(vec3 o, vec3 n, vec2 xi, out vec3 d, out float tmax, out float w)
{
#if HS_SOFT_SHAPE == 0
    vec2 c = hs_concentric(xi);
    d = normalize(u_light_vec + c.x * u_light_u + c.y * u_light_v);
    tmax = HS_FLT_BIG;
    w = max(dot(n, d), 0.0);
#elif HS_SOFT_SHAPE == 1
    vec3 w0 = u_light_vec - o;
    float dist2 = dot(w0, w0);
    float r2 = u_light_radius * u_light_radius;
    if (dist2 <= r2) { d = w0; tmax = 1.0; w = 1.0; return; }   // inside the light
    float dist = sqrt(dist2);
    vec3 ax = w0 / dist;
    float cos_max = sqrt(max(0.0, 1.0 - r2 / dist2));
    float ct = 1.0 - xi.x * (1.0 - cos_max);
    float st = sqrt(max(0.0, 1.0 - ct * ct));
    float phi = 6.283185307179586 * xi.y;
    vec3 t1 = normalize(abs(ax.x) > 0.5 ? cross(ax, vec3(0.0, 1.0, 0.0)) : cross(ax, vec3(1.0, 0.0, 0.0)));
    vec3 t2 = cross(ax, t1);
    vec3 dir = ct * ax + st * (cos(phi) * t1 + sin(phi) * t2);
    float b = dot(dir, w0);
    float th = b - sqrt(max(0.0, r2 - (dist2 - b * b)));   // nearest point of the sphere
    d = dir * max(th, 0.0);
    tmax = 1.0;
    w = max(dot(n, dir), 0.0);
#else
#if HS_SOFT_SHAPE == 2
    vec2 c = 2.0 * xi - 1.0;
#else
    vec2 c = hs_concentric(xi);
#endif
    d = (u_light_vec + c.x * u_light_u + c.y * u_light_v) - o;
    tmax = 1.0;
    float l2 = dot(d, d);
    float ce = -dot(d, u_light_axis);   // emission cosine x |d|
    w = max(dot(n, d), 0.0) * max(ce, 0.0) / max(l2 * l2, 1e-30);
    if (u_light_spread.x >= 0.0 && ce > 0.0) {   // Cycles' soft-box spread
        float ca = ce * inversesqrt(max(l2, 1e-30));
        float ta = sqrt(max(1.0 - ca * ca, 0.0)) / ca;
        w *= max((u_light_spread.x - ta) * u_light_spread.y, 0.0);
    }
#endif
}

#endif // HS_SOFT_LIGHT_GLSL
