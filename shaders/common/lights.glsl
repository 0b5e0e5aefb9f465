// Blender lights, evaluated like Cycles/EEVEE for a delta light (units: core/gpu/lights.py; numpy mirror: core/oracle/lighting.py).
// Light table: an RGBA32F texture, 4 texels per light (row r at x = 4r .. 4r+3):
//   t0: world position xyz, type (0 sun, 1 point, 2 spot, 3 area)
//   t1: direction the light shines towards (unit), cos(spot_size / 2)
//   t2: radiometric colour: sun irradiance S*colour (W/m^2); point/spot intensity
//       P/(4 pi)*colour (W/sr); area (as a one-sided Lambertian point) P/pi*colour on its axis
//   t3: spot_blend, 0, 0, 0
#define LIGHT_SUN 0
#define LIGHT_POINT 1
#define LIGHT_SPOT 2
#define LIGHT_AREA 3
uniform sampler2D u_lights;

float smoothstep01(float x) {
    x = clamp(x, 0.0, 1.0);
    return x * x * (3.0 - 2.0 * x);
}

// Irradiance arriving at p from light `row` on a plane facing the light (before the cosine),
// and the unit direction towards the light.
vec3 light_incident(int row, vec3 p, out vec3 l) {
    vec4 t0 = texelFetch(u_lights, ivec2(4 * row + 0, 0), 0);
    vec4 t1 = texelFetch(u_lights, ivec2(4 * row + 1, 0), 0);
    vec4 t2 = texelFetch(u_lights, ivec2(4 * row + 2, 0), 0);
    int type = int(t0.w + 0.5);
    if (type == LIGHT_SUN) {
        l = -t1.xyz;
        return t2.rgb;
    }
    vec3 d = t0.xyz - p;
    float r2 = max(dot(d, d), 1e-12);
    l = d * inversesqrt(r2);
    float k = 1.0 / r2;
    float t = dot(-l, t1.xyz);     // cosine between the light's axis and the light->point direction
    if (type == LIGHT_SPOT) {
        float blend = texelFetch(u_lights, ivec2(4 * row + 3, 0), 0).x;
        float ch = t1.w;
        float s = (blend > 0.0) ? smoothstep01((t - ch) / ((1.0 - ch) * blend)) : (t > ch ? 1.0 : 0.0);
        k *= s;
    } else if (type == LIGHT_AREA) {
        k *= max(t, 0.0);
    }
    return t2.rgb * k;
}

// Lambert + normalised Blinn-Phong (F0 = 0.08 * specular, exponent from roughness).
vec3 brdf_cos(vec3 n, vec3 l, vec3 v, vec3 albedo, float specular, float roughness, int use_specular) {
    float c = dot(n, l);
    if (c <= 0.0) return vec3(0.0);
    vec3 f = albedo * (1.0 / 3.14159265358979);
    if (use_specular == 1) {
        float a = max(roughness * roughness, 0.03);
        float s = clamp(2.0 / (a * a) - 2.0, 1.0, 2048.0);
        vec3 h = normalize(l + v);
        float nh = max(dot(n, h), 0.0);
        f += vec3(0.08 * specular * (s + 8.0) / (8.0 * 3.14159265358979) * pow(nh, s));
    }
    return f * c;
}
