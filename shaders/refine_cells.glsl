// Refinement, per light, at the coarse grid's resolution: cell c (the pixels between samples
// c + (0|1, 0|1), common/refine_grid.glsl) gets the samples' value when its 2x2 samples exist and
// agree and (u_ring) so do the 4x4 around them, else -1 (its pixels need their own rays).

#ifdef VERTEX_SHADER
#include "common/fullscreen.glsl"
#endif

#ifdef FRAGMENT_SHADER
#include "common/refine_grid.glsl"

uniform int u_ring;
out float o_cell;

void main()
{
    ivec2 c = ivec2(gl_FragCoord.xy);
    ivec2 grid = sample_grid();
    float value = sample_value(c);
    bool ok = value >= 0.0 && all(lessThan(c + 1, grid));
    for (int k = 1; k < 4; ++k) {
        float v = ok ? sample_value(c + ivec2(k & 1, k >> 1)) : value;
        ok = ok && v == value;
    }
    if (u_ring != 0) {
        for (int k = 0; k < 16; ++k) {
            ivec2 o = ivec2(k & 3, k >> 2) - 1;
            bool inner = (o.x == 0 || o.x == 1) && (o.y == 0 || o.y == 1);
            ivec2 q = c + o;
            if (inner || any(lessThan(q, ivec2(0))) || any(greaterThanEqual(q, grid))) continue;
            float v = sample_value(q);
            ok = ok && (v < 0.0 || v == value);
        }
    }
    o_cell = ok ? value : -1.0;
}
#endif
