/* soft_light.glsl -- points on an extended light for soft shadows (HS_SOFT), included by
 * raytrace.glsl after common/shadow_ray.glsl. Mirror: hybrid_shadow_addon/core/oracle/soft.py.
 *
 * HS_SOFT_SHAPE: 0 a sun of angular diameter a (directions through a disk of radius tan(a/2)
 * in the plane across the sun's direction, as Cycles samples a distant light), 1 a sphere light
 * of radius r (point and spot lights with a radius: directions uniform in the cone it subtends),
 * 2 a rectangle, 3 an ellipse (area lights: points uniform on the surface; a spread below 180°
 * weighs each point by Cycles' soft-box attenuation of the direction towards the receiver). A
 * spot light with a radius weighs each point by the spot's cone and blend seen from that point,
 * as Cycles does, so its cone's edge is soft too (shadow_ray.glsl widens its reach test to match).
 * u_light_radius is declared by shadow_ray.glsl.
 *
 * Each sample k of a pixel is a 2D point of the Sobol sequence, Owen-scrambled with a per-pixel,
 * per-light hash (Burley 2020): stratified within a pixel, decorrelated between pixels, and a
 * frame that continues at u_sample_base carries on the same sequence (against Cycles on
 * soft_lights it is 10-25 % less wrong than a rotated R2 sequence at the same samples). A sample's
 * weight is what Cycles weights that point of the light by in the unshadowed irradiance
 * (receiver cosine; an area light's cosine and 1/r^2 as well), so the mask is the weighted
 * fraction of the light visible: sum(w v) / sum(w). A pixel none of whose samples has a weight
 * (only a sliver of the light above its horizon) takes one ray to the light's highest point
 * (hs_light_top), as the oracle does.
 */
#ifndef HS_SOFT_LIGHT_GLSL
#define HS_SOFT_LIGHT_GLSL

#include "common/soft_probe.glsl"

uniform int u_samples;        // rays per pixel (>= 1)
uniform int u_sample_base;    // index of this frame's first sample in each pixel's sequence
uniform uint u_seed;          // per light
uniform vec3 u_light_u;       // sun: tangent axis x tan(angle / 2); area: half-extent axes
uniform vec3 u_light_v;
uniform float u_light_blend;  // spot blend (a sphere light that is a spot; u_light_cone is its cone)
uniform vec2 u_light_spread;  // area light: (tan of the half spread, its normalisation); x < 0: none

uint hs_hash(uvec3 v)
{
    // pcg3d (Jarzynski & Olano 2020), first component
    v = v * 1664525u + 1013904223u;
    v.x += v.y * v.z; v.y += v.z * v.x; v.z += v.x * v.y;
    v ^= v >> 16u;
    v.x += v.y * v.z; v.y += v.z * v.x; v.z += v.x * v.y;
    return v.x;
}

// Owen scrambling of a 32-bit binary fraction (Burley 2020's hash-based nested uniform
// scramble: the Laine-Karras permutation on the reversed bits)
uint hs_owen(uint x, uint seed)
{
    x = bitfieldReverse(x);
    x += seed;
    x ^= x * 0x6c50b47cu;
    x ^= x * 0xb82f1e52u;
    x ^= x * 0xc7afe638u;
    x ^= x * 0x8d22f6e6u;
    return bitfieldReverse(x);
}

// Sample k of pixel px: the first two dimensions of the Sobol sequence (a (0,2)-sequence: every
// power-of-two prefix is stratified in all elementary intervals), Owen-scrambled with seeds
// from a hash of the pixel and the light, so pixels are decorrelated and a frame that continues
// at u_sample_base carries on the same sequence
uvec2 hs_sample_seeds(ivec2 px)
{
    uint seed = hs_hash(uvec3(uvec2(px), u_seed));
    return uvec2(seed, hs_hash(uvec3(seed, 0x9E3779B9u, u_seed)));
}

// (with the pixel's seeds, hs_sample_seeds: a loop over a pixel's samples hashes once)
vec2 hs_sample2s(uvec2 seeds, int k)
{
    uint i = uint(k);
    uint y = 0u;
    for (uint v = 0x80000000u, b = i; b != 0u; b >>= 1u, v ^= v >> 1u)
        if ((b & 1u) != 0u) y ^= v;
    uint x = bitfieldReverse(i);
    x = hs_owen(x, seeds.x);
    y = hs_owen(y, seeds.y);
    return vec2(float(x >> 8u), float(y >> 8u)) * (1.0 / 16777216.0);
}

vec2 hs_sample2(ivec2 px, int k) { return hs_sample2s(hs_sample_seeds(px), k); }

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

#if HS_SOFT_SHAPE == 1
// A spot's cone and blend for the direction light -> p, as lights.glsl and Cycles weigh each
// point of a spot light (1 inside the cone, 0 outside; a point light: u_light_cone < -1, 1).
float hs_spot_weight(vec3 light_to_p)
{
    float t = dot(normalize(light_to_p), u_light_axis);
    float ch = u_light_cone;
    if (u_light_blend > 0.0) {
        float x = clamp((t - ch) / ((1.0 - ch) * u_light_blend), 0.0, 1.0);
        return x * x * (3.0 - 2.0 * x);
    }
    return t > ch ? 1.0 : 0.0;
}

// The ray from o towards the sphere light along dir (a unit direction within the cone the
// sphere subtends, axis ax = the unit direction to its centre w0) and its weight.
void hs_sphere_ray(vec3 o, vec3 n, vec3 w0, vec3 dir, out vec3 d, out float tmax, out float w)
{
    float r2 = u_light_radius * u_light_radius;
    float dist2 = dot(w0, w0);
    float b = dot(dir, w0);
    float th = b - sqrt(max(0.0, r2 - (dist2 - b * b)));   // nearest point of the sphere
    d = dir * max(th, 0.0);
    tmax = 1.0;
    w = max(dot(n, dir), 0.0) * hs_spot_weight(-dir);   // (the point lies along dir from o)
}
#else
// The ray from o towards the point c of the light (shape 0: the unit disk of directions across
// the sun's; 2: the rectangle's [-1, 1]^2; 3: the ellipse's unit disk) and its weight.
void hs_light_ray(vec3 o, vec3 n, vec2 c, out vec3 d, out float tmax, out float w)
{
#if HS_SOFT_SHAPE == 0
    d = normalize(u_light_vec + c.x * u_light_u + c.y * u_light_v);
    tmax = HS_FLT_BIG;
    w = max(dot(n, d), 0.0);
#else
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
#endif

// Sample xi of the light seen from o (normal n): the ray o + t d, t in (0, tmax), and its weight.
void hs_light_sample(vec3 o, vec3 n, vec2 xi, out vec3 d, out float tmax, out float w)
{
#if HS_SOFT_SHAPE == 1
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
    hs_sphere_ray(o, n, w0, ct * ax + st * (cos(phi) * t1 + sin(phi) * t2), d, tmax, w);
#elif HS_SOFT_SHAPE == 2
    hs_light_ray(o, n, 2.0 * xi - 1.0, d, tmax, w);
#else
    hs_light_ray(o, n, hs_concentric(xi), d, tmax, w);
#endif
}

// The light's point highest above o's horizon (pulled 0.1 % inside the light): the ray that
// decides a pixel none of whose samples reached above the horizon, where only a sliver of the
// light is (its share of the sliver is that point's visibility as the sliver shrinks).
void hs_light_top(vec3 o, vec3 n, out vec3 d, out float tmax, out float w)
{
    const float inside = 0.999;
#if HS_SOFT_SHAPE == 1
    vec3 w0 = u_light_vec - o;
    float dist2 = dot(w0, w0);
    float r2 = u_light_radius * u_light_radius;
    if (dist2 <= r2) { d = w0; tmax = 1.0; w = 1.0; return; }
    vec3 ax = w0 * inversesqrt(dist2);
    vec3 q = n - ax * dot(n, ax);   // towards n, across the axis
    float lq = length(q);
    float sb = inside * sqrt(r2 / dist2);   // sine of (almost) the cone's half angle
    vec3 dir = lq > 1e-12 ? sqrt(1.0 - sb * sb) * ax + sb * (q / lq) : ax;
    hs_sphere_ray(o, n, w0, dir, d, tmax, w);
#else
    vec2 g = vec2(dot(n, u_light_u), dot(n, u_light_v));
#if HS_SOFT_SHAPE == 2
    vec2 c = inside * sign(g);      // the corner the normal leans to
#else
    float lg = length(g);
    vec2 c = lg > 0.0 ? inside * g / lg : vec2(0.0);
#endif
    hs_light_ray(o, n, c, d, tmax, w);
#endif
}

#endif // HS_SOFT_LIGHT_GLSL
