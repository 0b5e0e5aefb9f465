/* linking.glsl -- light and shadow linking (HS_LINKING: some light has a receiver or blocker
 * collection; core/scene/linking.py, core/gpu/linking.py).
 *
 * [link]  RGBA32UI "hs_link_tex", 1 texel per instance (texel i at (i & 1023, i >> 10)): the
 *         instance's light-set bits (low, high word), then its shadow-set bits (low, high).
 * A light's receiver set (light set) and blocker set (shadow set), -1 for none: the ray pass's
 * u_link_receiver / u_link_blocker uniforms; the lighting pass's "hs_link_lights_tex" (R32I,
 * texel r: the receiver set of light table row r). Rays towards a light skip the instances not in
 * its blocker set; a light gives no light to the pixels whose instance is not in its receiver set.
 */
#ifndef HS_LINKING_GLSL
#define HS_LINKING_GLSL
#ifdef HS_LINKING
#define HS_LINK_WIDTH_LOG2 10

uniform usampler2D hs_link_tex;
uniform int u_link_blocker;    // the traced light's shadow set, -1: every caster blocks it

uvec4 hs_link_member(int inst) {
    return texelFetch(hs_link_tex, ivec2(inst & ((1 << HS_LINK_WIDTH_LOG2) - 1), inst >> HS_LINK_WIDTH_LOG2), 0);
}

bool hs_link_has(uvec2 bits, int s) {
    uint w = s < 32 ? bits.x : bits.y;
    return ((w >> uint(s & 31)) & 1u) != 0u;
}

// whether instance inst casts the traced light's shadows
bool hs_link_blocks(int inst) {
    return u_link_blocker < 0 || hs_link_has(hs_link_member(inst).zw, u_link_blocker);
}

// whether a light of receiver set s lights instance inst
bool hs_link_receives(int inst, int s) {
    return s < 0 || inst < 0 || hs_link_has(hs_link_member(inst).xy, s);
}
#endif
#endif // HS_LINKING_GLSL
