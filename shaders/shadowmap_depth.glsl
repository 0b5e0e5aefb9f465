// Shadow-map depth: linear depth from the light (metres along the view's forward axis) into an
// R32F atlas tile, resolved with MIN blending (exact, no depth-buffer precision involved).
// ALPHA: casters whose material's alpha cuts the shadow (in_uv, in_matid): fragments that let
// more than half of the light through are dropped (common/alpha.glsl's transmittance, the same
// test as the ray-traced any-hit).
#ifdef VERTEX_SHADER
layout(location = 0) in vec3 in_pos;
in vec4 in_m0; in vec4 in_m1; in vec4 in_m2;   // rows of the camera-relative world matrix
uniform mat4 u_light_clip_from_rel;
out vec3 v_rel;
#ifdef ALPHA
in vec2 in_uv;
in float in_matid;
out vec2 v_uv;
flat out int v_matid;
#endif
void main() {
#ifdef ALPHA
    v_uv = in_uv;
    v_matid = int(in_matid);
#endif
    vec4 p = vec4(in_pos, 1.0);
    v_rel = vec3(dot(in_m0, p), dot(in_m1, p), dot(in_m2, p));
    gl_Position = u_light_clip_from_rel * vec4(v_rel, 1.0);
}
#endif

#ifdef FRAGMENT_SHADER
uniform vec3 u_light_origin_rel;
uniform vec3 u_light_fwd;
in vec3 v_rel;
layout(location = 0) out float o_depth;
#ifdef ALPHA
#include "common/alpha.glsl"
in vec2 v_uv;
flat in int v_matid;
#endif
void main() {
#ifdef ALPHA
    if (hs_transmittance(v_matid, v_uv) > 0.5) discard;
#endif
    o_depth = dot(v_rel - u_light_origin_rel, u_light_fwd);
}
#endif
