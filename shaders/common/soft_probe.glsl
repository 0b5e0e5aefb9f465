/* soft_probe.glsl -- the probe pass's output (raytrace.glsl with HS_SOFT_PROBE): RG32F sums
 * (weighted visibility, weight) of each pixel's first HS_PROBES samples, (value, 1) where the
 * answer is known without a ray. Read by raytrace.glsl (HS_SOFT_REFINE, through soft_light.glsl)
 * and soft_range.glsl (SUMS).
 */
#ifndef HS_SOFT_PROBE_GLSL
#define HS_SOFT_PROBE_GLSL

#define HS_PROBES 1           // rays per pixel of the probe pass (SOFT_PROBES of soft.py)
#define HS_PROBE_RADIUS 4     // a pixel takes its probe answer when every probe within this
                              // many pixels saw all or none of the light alike (soft_range.glsl)
// (1 probe within 4 pixels, 81 rays around a pixel, against 2 within 3, 98: as exact against
// Cycles on soft_lights, forest, clusters and alpha_cards, a soft render 2-23 % cheaper;
// BENCHMARKS.md "One probe over 4 pixels")

// The probe answer from its sums: -1 where no probe had any weight (not known).
float hs_probe_value(vec2 sums) { return sums.y > 0.0 ? sums.x / sums.y : -1.0; }

#endif // HS_SOFT_PROBE_GLSL
