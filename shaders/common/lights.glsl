// Blender lights, evaluated as Cycles/EEVEE emit them (units: core/gpu/lights.py; numpy mirror:
// core/oracle/lighting.py).
// Light table: HS_LIGHT_TEXELS RGBA32F texels per light (row r at 5r .. 5r+4), in a uniform block
// of HS_LIGHT_ROWS texels where it fits, else a texture:
//   t0: world position xyz, type (0 sun, 1 point, 2 spot, 3 area)
//   t1: direction the light shines towards (unit), cos(spot_size / 2)
//   t2: radiometric colour: sun irradiance S*colour (W/m^2); point/spot intensity
//       P/(4 pi)*colour (W/sr); area radiance P/(pi A)*colour (W/m^2/sr), or for a zero-size
//       area light its on-axis intensity P/pi*colour
//   t3: spot_blend, area half height, area shape (0 rectangle, 1 ellipse), tan of the area
//       light's half spread (< 0: no spread); t2.w its normalisation (Cycles' soft-box grid)
//   t4: area light's unit x axis, half width (0: a zero-size area light, a Lambertian point)
//
// The kinds of light the pass may meet are defines (core/gpu/lights.py lighting_defines, from the
// light table itself), so a scene pays only for what it has: a software rasteriser runs every
// branch of a lane group whatever its lights, and an area light's polygon costs several times
// a point light. HS_LIT_SUN, HS_LIT_POINT, HS_LIT_SPOT, HS_LIT_AREA_POINT (an area light of
// size 0), HS_LIT_AREA_RECT and HS_LIT_AREA_ELLIPSE (sized, no spread), HS_LIT_AREA_SPREAD
// (sized, spread below 180°). A light of a kind not defined contributes nothing.
#define LIGHT_SUN 0
#define LIGHT_POINT 1
#define LIGHT_SPOT 2
#define LIGHT_AREA 3
#define HS_LIGHT_TEXELS 5
#define HS_PI 3.14159265358979
#define HS_ELLIPSE_SIDES 24
#if defined(HS_LIT_POINT) || defined(HS_LIT_SPOT) || defined(HS_LIT_AREA_POINT)
#define HS_LIT_LOCAL_POINT
#endif
#if defined(HS_LIT_AREA_RECT) || defined(HS_LIT_AREA_ELLIPSE)
#define HS_LIT_AREA_POLY
#endif
#if defined(HS_LIT_AREA_POLY) || defined(HS_LIT_AREA_SPREAD)
#define HS_LIT_AREA_SIZED
#endif
#ifdef HS_LIT_AREA_ELLIPSE
#define HS_POLY_MAX HS_ELLIPSE_SIDES
#else
#define HS_POLY_MAX 4
#endif
#ifdef HS_LIGHT_ROWS
// the table in a uniform block where it fits (passes/lighting.py): a light's row is the same for
// every pixel, and llvmpipe reads a uniform block at such an index once for a lane group, a
// texture once per lane
layout(std140) uniform HsLights { vec4 hs_light_rows[HS_LIGHT_ROWS]; };
vec4 light_texel(int row, int k) { return hs_light_rows[HS_LIGHT_TEXELS * row + k]; }
#else
uniform sampler2D u_lights;
vec4 light_texel(int row, int k) { return texelFetch(u_lights, ivec2(HS_LIGHT_TEXELS * row + k, 0), 0); }
#endif

float smoothstep01(float x) {
    x = clamp(x, 0.0, 1.0);
    return x * x * (3.0 - 2.0 * x);
}

// Irradiance arriving at p from light `row` on a plane facing the light (before the cosine),
// and the unit direction towards the light (an area light: its far field from its centre).
vec3 light_incident(int row, vec3 p, out vec3 l) {
    vec4 t0 = light_texel(row, 0);
    vec4 t1 = light_texel(row, 1);
    vec4 t2 = light_texel(row, 2);
    int type = int(t0.w + 0.5);
#ifdef HS_LIT_SUN
    if (type == LIGHT_SUN) {
        l = -t1.xyz;
        return t2.rgb;
    }
#endif
#ifdef HS_LIT_LOCAL_POINT
    vec3 d = t0.xyz - p;
    float r2 = max(dot(d, d), 1e-12);
    l = d * inversesqrt(r2);
    float k = 1.0 / r2;
    float t = dot(-l, t1.xyz);     // cosine between the light's axis and the light->point direction
#ifdef HS_LIT_SPOT
    if (type == LIGHT_SPOT) {
        float blend = light_texel(row, 3).x;
        float ch = t1.w;
        float s = (blend > 0.0) ? smoothstep01((t - ch) / ((1.0 - ch) * blend)) : (t > ch ? 1.0 : 0.0);
        k *= s;
    }
#endif
#ifdef HS_LIT_AREA_POINT
    if (type == LIGHT_AREA) k *= max(t, 0.0);
#endif
    return t2.rgb * k;
#else
    l = vec3(0.0, 0.0, 1.0);
    return vec3(0.0);
#endif
}

// Lambert + normalised Blinn-Phong (F0 = 0.08 * specular, exponent from roughness); the
// diffuse and specular parts of BRDF * cos apart.
vec3 specular_cos(vec3 n, vec3 l, vec3 v, float specular, float roughness) {
    float c = dot(n, l);
    if (c <= 0.0) return vec3(0.0);
    float a = max(roughness * roughness, 0.03);
    float s = clamp(2.0 / (a * a) - 2.0, 1.0, 2048.0);
    vec3 h = normalize(l + v);
    float nh = max(dot(n, h), 0.0);
    return vec3(0.08 * specular * (s + 8.0) / (8.0 * HS_PI) * pow(nh, s) * c);
}

vec3 brdf_cos(vec3 n, vec3 l, vec3 v, vec3 albedo, float specular, float roughness, int use_specular) {
    float c = dot(n, l);
    if (c <= 0.0) return vec3(0.0);
    vec3 f = albedo * (c / HS_PI);
    if (use_specular == 1) f += specular_cos(n, l, v, specular, roughness);
    return f;
}

// Irradiance at p (normal n) from a uniformly emitting polygon of unit radiance, the polygon
// clipped to p's upper hemisphere (Lambert's formula: E = 1/2 sum over edges of the angle
// subtended times the cosine of the edge plane's normal with n).
#ifdef HS_LIT_AREA_POLY
float polygon_irradiance(vec3 verts[HS_POLY_MAX], int count, vec3 p, vec3 n) {
    float sum = 0.0;
    vec3 prev = verts[count - 1] - p;
    float hp = dot(prev, n);
    vec3 first_in = vec3(0.0);
    // Sutherland-Hodgman against the plane dot(x, n) = 0, integrating each kept edge at once
    vec3 last = vec3(0.0);
    bool have_last = false;
    for (int i = 0; i < HS_POLY_MAX; ++i) {
        if (i >= count) break;
        vec3 cur = verts[i] - p;
        float hc = dot(cur, n);
        vec3 outv[2];
        int k = 0;
        if (hc > 0.0) {
            if (hp <= 0.0) outv[k++] = prev + (cur - prev) * (hp / (hp - hc));
            outv[k++] = cur;
        } else if (hp > 0.0) {
            outv[k++] = prev + (cur - prev) * (hp / (hp - hc));
        }
        for (int j = 0; j < 2; ++j) {
            if (j >= k) break;
            vec3 u = normalize(outv[j]);
            if (have_last) {
                vec3 g = cross(last, u);
                float lg = length(g);
                if (lg > 0.0) sum += atan(lg, dot(last, u)) * dot(n, g) / lg;
            } else {
                first_in = u;
            }
            last = u;
            have_last = true;
        }
        prev = cur;
        hp = hc;
    }
    if (have_last) {
        vec3 g = cross(last, first_in);
        float lg = length(g);
        if (lg > 0.0) sum += atan(lg, dot(last, first_in)) * dot(n, g) / lg;
    }
    return 0.5 * abs(sum);
}
#endif

// Irradiance from an area light with a spread below 180°: the emitted radiance falls off with
// the angle from the axis (max((tan h - tan a) N, 0), Cycles' soft-box grid), which no polygon
// formula integrates: 8 x 8 Gauss-Legendre nodes over the rectangle (an ellipse in polar
// coordinates), the receiver's cosine clamped at its horizon.
#ifdef HS_LIT_AREA_SPREAD
const float HS_GL8_X[4] = float[4](0.1834346424956498, 0.5255324099163290, 0.7966664774136267, 0.9602898564975363);
const float HS_GL8_W[4] = float[4](0.3626837833783620, 0.3137066458778873, 0.2223810344533745, 0.1012285362903763);

float hs_gl8_node(int i) { return i < 4 ? -HS_GL8_X[3 - i] : HS_GL8_X[i - 4]; }
float hs_gl8_weight(int i) { return i < 4 ? HS_GL8_W[3 - i] : HS_GL8_W[i - 4]; }

float spread_irradiance(vec3 c, vec3 axis, vec3 ex, vec3 ey, bool ellipse, vec2 spread, vec3 p, vec3 n) {
    float sum = 0.0;
    for (int i = 0; i < 8; ++i) {
        for (int j = 0; j < 8; ++j) {
            float a = hs_gl8_node(i), b = hs_gl8_node(j);
            float w = hs_gl8_weight(i) * hs_gl8_weight(j);
            vec3 q;
            if (ellipse) {   // radius (a + 1) / 2 in (0, 1), angle pi (b + 1)
                float r = 0.5 * (a + 1.0), phi = HS_PI * (b + 1.0);
                q = c + r * (cos(phi) * ex + sin(phi) * ey);
                w *= 0.5 * r * HS_PI;   // dr = da / 2, dphi = pi db, the Jacobian r
            } else {
                q = c + a * ex + b * ey;
            }
            vec3 d = q - p;
            float r2 = max(dot(d, d), 1e-12);
            float inv = inversesqrt(r2);
            float cr = max(dot(d, n), 0.0) * inv;
            float cl = max(-dot(d, axis), 0.0) * inv;
            float ta = sqrt(max(1.0 - cl * cl, 0.0)) / max(cl, 1e-12);
            float f = cl > 0.0 ? max((spread.x - ta) * spread.y, 0.0) : 0.0;
            sum += w * cr * cl * f / r2;
        }
    }
    return sum * length(ex) * length(ey);
}
#endif

// Irradiance at p (normal n) from area light `row` (rectangle or equal-area 24-gon ellipse), 0
// behind its emitting side.
#ifdef HS_LIT_AREA_SIZED
vec3 area_irradiance(int row, vec3 p, vec3 n) {
    vec4 t0 = light_texel(row, 0);
    vec4 t1 = light_texel(row, 1);
    vec4 t3 = light_texel(row, 3);
    vec4 t4 = light_texel(row, 4);
    vec3 c = t0.xyz;
    vec3 axis = t1.xyz;
    if (dot(p - c, axis) <= 0.0) return vec3(0.0);
    vec3 ex = t4.xyz * t4.w;
    vec3 ey = normalize(cross(axis, t4.xyz)) * t3.y;
#ifdef HS_LIT_AREA_SPREAD
    if (t3.w >= 0.0)
        return light_texel(row, 2).rgb * spread_irradiance(c, axis, ex, ey, t3.z >= 0.5,
                                                           vec2(t3.w, light_texel(row, 2).w), p, n);
#endif
#ifdef HS_LIT_AREA_POLY
    vec3 verts[HS_POLY_MAX];
    int count = 4;
#ifdef HS_LIT_AREA_RECT
    if (t3.z < 0.5) {
        verts[0] = c - ex - ey; verts[1] = c + ex - ey; verts[2] = c + ex + ey; verts[3] = c - ex + ey;
        count = 4;
    }
#endif
#ifdef HS_LIT_AREA_ELLIPSE
    if (t3.z >= 0.5) {
        // equal area: an inscribed N-gon of radius k covers (N/2) sin(2 pi/N) k^2 = pi
        const float k = 1.00574;   // sqrt(2 pi / (N sin(2 pi / N))), N = 24
        for (int i = 0; i < HS_ELLIPSE_SIDES; ++i) {
            float a = 2.0 * HS_PI * float(i) / float(HS_ELLIPSE_SIDES);
            verts[i] = c + k * (cos(a) * ex + sin(a) * ey);
        }
        count = HS_ELLIPSE_SIDES;
    }
#endif
    return light_texel(row, 2).rgb * polygon_irradiance(verts, count, p, n);
#else
    return vec3(0.0);
#endif
}
#endif

// Outgoing radiance at p from light `row`, before its shadow mask: a sized area light
// (area_contribution) or any other (point_contribution). The lighting pass keeps the two kinds
// in loops of their own (lighting.glsl): on a software rasteriser a branch on the light's kind
// costs every light the polygon's code, whatever its kind.
#ifdef HS_LIT_AREA_SIZED
vec3 area_contribution(int row, vec3 p, vec3 n, vec3 v, vec3 albedo, float specular, float roughness,
                       int use_specular) {
    // diffuse: the exact irradiance of the polygon; specular: its far field from the centre
    vec3 c = albedo * (1.0 / HS_PI) * area_irradiance(row, p, n);
    if (use_specular == 1) {
        vec3 l;
        vec3 d = light_texel(row, 0).xyz - p;
        float r2 = max(dot(d, d), 1e-12);
        l = d * inversesqrt(r2);
        vec4 t3 = light_texel(row, 3);
        float area = 4.0 * light_texel(row, 4).w * t3.y * (t3.z < 0.5 ? 1.0 : HS_PI / 4.0);
        float t = max(dot(-l, light_texel(row, 1).xyz), 0.0);
        c += light_texel(row, 2).rgb * (area * t / r2) * specular_cos(n, l, v, specular, roughness);
    }
    return c;
}
#endif

vec3 point_contribution(int row, vec3 p, vec3 n, vec3 v, vec3 albedo, float specular, float roughness,
                        int use_specular) {
    vec3 l;
    vec3 e = light_incident(row, p, l);
    return e * brdf_cos(n, l, v, albedo, specular, roughness, use_specular);
}
