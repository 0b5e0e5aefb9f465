/* alpha.glsl -- textured and alpha-cut materials: image sampling from the atlas, a material's
 * alpha and the transmittance of a shadow ray crossing it. Used by the traversal's any-hit test
 * (HS_HAS_ALPHA, common/scene_bvh.glsl), the G-buffer (TEXTURED) and the shadow-map depth pass.
 * Bake: hybrid_shadow_addon/core/bake/materials.py. Oracle: core/oracle/alpha.py (the same rule).
 *
 * [mat]   RGBA32UI "hs_mat_tex", linear texels (hs_mat_texel), width a power of two:
 *   material k, texels 3k .. 3k+2:
 *     3k    .xyz bits(row 0 of the UV transform: u' = dot(row0, (u, v, 1))), .w bits(alpha)
 *     3k+1  .xyz bits(row 1), .w bits(alpha threshold)
 *     3k+2  .x 1 + colour image record (0: none), .y 1 + alpha image record (0: none),
 *           .z flags (1: CLIP, 2: LUMA alpha, 4: transparent shadow), .w 0
 *   image record r: texel r = (levels, extension 0 REPEAT 1 EXTEND 2 CLIP 3 MIRROR,
 *           interpolation 0 Linear 1 Closest 2 Cubic, sRGB), texel r + 1 + l = mip level l:
 *           (x, y, layer, width | height << 16) of its rectangle in the atlas
 * [atlas] RGBA8 "hs_atlas_tex" (sampler2DArray, normalised): the images' stored bytes.
 *
 * Sampling (core/scene/materials.py Image): texel (i, j) centred at ((i + .5) / W, (j + .5) / H);
 * Linear blends the 4 nearest texels, Closest takes floor(uv * size), Cubic weighs the 4x4 nearest
 * with Cycles' cubic B-spline; the extension applies to each texel index (CLIP: a UV outside
 * [0, 1) reads 0, texels outside the image are 0). An alpha (the G-buffer's coverage, a shadow
 * ray's cut) reads level 0 with the image's own interpolation, as Cycles reads the image at a
 * hit; colour reads the mip levels, bilinear in place of cubic.
 */
#ifndef HS_ALPHA_GLSL
#define HS_ALPHA_GLSL

#define HS_MAT_TEXELS 3
#define HS_MAT_CLIP 1u
#define HS_MAT_LUMA 2u
#define HS_MAT_TRANSPARENT 4u

uniform usampler2DArray hs_mat_tex;
uniform sampler2DArray hs_atlas_tex;

uvec4 hs_mat(int i)
{
    int w = textureSize(hs_mat_tex, 0).x;   // a power of two
    int row = i / w;
    return texelFetch(hs_mat_tex, ivec3(i - row * w, row & 16383, row >> 14), 0);
}

// floor division that is defined for negative i (GLSL's % and / are not)
int hs_floor_div(int i, int n) { return i >= 0 ? i / n : -((n - 1 - i) / n); }

// texel index i of an image n wide under extension ext; -1: outside (CLIP)
int hs_wrap(int i, int n, uint ext)
{
    if (ext == 0u) return i - n * hs_floor_div(i, n);
    if (ext == 1u) return clamp(i, 0, n - 1);
    if (ext == 3u) {
        int m = i - 2 * n * hs_floor_div(i, 2 * n);
        return m < n ? m : 2 * n - 1 - m;
    }
    return (i < 0 || i >= n) ? -1 : i;
}

vec4 hs_img_texel(uvec4 lvl, ivec2 size, int i, int j, uint ext)
{
    int x = hs_wrap(i, size.x, ext), y = hs_wrap(j, size.y, ext);
    if (x < 0 || y < 0) return vec4(0.0);
    return texelFetch(hs_atlas_tex, ivec3(int(lvl.x) + x, int(lvl.y) + y, int(lvl.z)), 0);
}

// Cycles' cubic B-spline weights of the 4 texels around a sample t of the way past the second.
vec4 hs_bspline(float t)
{
    return vec4((((-1.0 / 6.0) * t + 0.5) * t - 0.5) * t + (1.0 / 6.0),
                ((0.5 * t - 1.0) * t) * t + (2.0 / 3.0),
                ((-0.5 * t + 0.5) * t + 0.5) * t + (1.0 / 6.0),
                (1.0 / 6.0) * t * t * t);
}

// Cubic B-spline over the 4x4 texels around texel coordinate st (Cycles' Cubic and Smart).
vec4 hs_sample_cubic(uvec4 lvl, ivec2 size, vec2 st, uint ext)
{
    vec2 f = st - 0.5;
    vec2 fl = floor(f);
    vec4 wx = hs_bspline(f.x - fl.x), wy = hs_bspline(f.y - fl.y);
    ivec2 i0 = ivec2(fl) - 1;
    vec4 acc = vec4(0.0);
    for (int j = 0; j < 4; ++j) {
        vec4 row = wx.x * hs_img_texel(lvl, size, i0.x, i0.y + j, ext)
                 + wx.y * hs_img_texel(lvl, size, i0.x + 1, i0.y + j, ext)
                 + wx.z * hs_img_texel(lvl, size, i0.x + 2, i0.y + j, ext)
                 + wx.w * hs_img_texel(lvl, size, i0.x + 3, i0.y + j, ext);
        acc += wy[j] * row;
    }
    return acc;
}

// Sample level lvl (its record texel) of the image whose header texel is head, stored values.
vec4 hs_sample_rec(uvec4 head, uvec4 lvl, vec2 uv)
{
    uint ext = head.y;
    if (ext == 2u && (uv.x < 0.0 || uv.x >= 1.0 || uv.y < 0.0 || uv.y >= 1.0)) return vec4(0.0);
    ivec2 size = ivec2(int(lvl.w & 0xFFFFu), int(lvl.w >> 16u));
    vec2 st = uv * vec2(size);
    if (head.z == 2u) return hs_sample_cubic(lvl, size, st, ext);
    if (head.z == 1u) {
        ivec2 ij = ivec2(floor(st));
        return hs_img_texel(lvl, size, ij.x, ij.y, ext);
    }
    vec2 f = st - 0.5;
    vec2 fl = floor(f);
    vec2 w = f - fl;
    ivec2 i0 = ivec2(fl);
    vec4 c00 = hs_img_texel(lvl, size, i0.x, i0.y, ext);
    vec4 c10 = hs_img_texel(lvl, size, i0.x + 1, i0.y, ext);
    vec4 c01 = hs_img_texel(lvl, size, i0.x, i0.y + 1, ext);
    vec4 c11 = hs_img_texel(lvl, size, i0.x + 1, i0.y + 1, ext);
    return mix(mix(c00, c10, w.x), mix(c01, c11, w.x), w.y);
}

// Image record rec (texel index) at mip level (clamped to its levels), stored values; exact:
// with the image's interpolation, else bilinear in place of cubic (the colour's mip levels).
vec4 hs_sample_image(int rec, vec2 uv, int level, bool exact)
{
    uvec4 head = hs_mat(rec);
    uvec4 lvl = hs_mat(rec + 1 + clamp(level, 0, int(head.x) - 1));
    if (!exact && head.z == 2u) head.z = 0u;
    return hs_sample_rec(head, lvl, uv);
}

bool hs_image_srgb(int rec) { return hs_mat(rec).w != 0u; }

vec3 hs_srgb_decode(vec3 c)
{
    return mix(c / 12.92, pow((c + 0.055) / 1.055, vec3(2.4)), greaterThan(c, vec3(0.04045)));
}

// The material's UV transform applied to mesh UVs.
vec2 hs_material_uv(int mat, vec2 uv)
{
    vec3 r0 = uintBitsToFloat(hs_mat(HS_MAT_TEXELS * mat).xyz);
    vec3 r1 = uintBitsToFloat(hs_mat(HS_MAT_TEXELS * mat + 1).xyz);
    vec3 p = vec3(uv, 1.0);
    return vec2(dot(r0, p), dot(r1, p));
}

// Alpha of material mat at mesh UV uv (level 0, the image's interpolation: as Cycles' rays see it).
float hs_material_alpha(int mat, vec2 uv)
{
    uvec4 t0 = hs_mat(HS_MAT_TEXELS * mat);
    uvec4 t2 = hs_mat(HS_MAT_TEXELS * mat + 2);
    float a = uintBitsToFloat(t0.w);
    if (t2.y != 0u) {
        int rec = int(t2.y) - 1;
        vec4 c = hs_sample_image(rec, hs_material_uv(mat, uv), 0, true);
        if ((t2.z & HS_MAT_LUMA) != 0u) {
            vec3 rgb = hs_image_srgb(rec) ? hs_srgb_decode(c.rgb) : c.rgb;
            a *= dot(rgb, vec3(0.2126, 0.7152, 0.0722));
        } else {
            a *= c.a;
        }
    }
    return a;
}

// Light a shadow ray keeps crossing material mat at mesh UV uv: BLEND 1 - alpha, CLIP 1 below
// the threshold else 0; 0 without transparent shadows.
float hs_transmittance(int mat, vec2 uv)
{
    uvec4 t1 = hs_mat(HS_MAT_TEXELS * mat + 1);
    uvec4 t2 = hs_mat(HS_MAT_TEXELS * mat + 2);
    if ((t2.z & HS_MAT_TRANSPARENT) == 0u) return 0.0;
    float a = hs_material_alpha(mat, uv);
    if ((t2.z & HS_MAT_CLIP) != 0u) return a < uintBitsToFloat(t1.w) ? 1.0 : 0.0;
    return clamp(1.0 - a, 0.0, 1.0);
}

// A material's shadow cut read once (per instance the traversal enters), so each triangle hit
// costs its UVs and the image's texels only.
struct HsCut { vec3 r0; vec3 r1; float alpha; float thr; uint flags; uvec4 head; uvec4 lvl; };

HsCut hs_cut_setup(int mat)
{
    uvec4 t0 = hs_mat(HS_MAT_TEXELS * mat);
    uvec4 t1 = hs_mat(HS_MAT_TEXELS * mat + 1);
    uvec4 t2 = hs_mat(HS_MAT_TEXELS * mat + 2);
    HsCut c;
    c.r0 = uintBitsToFloat(t0.xyz);
    c.r1 = uintBitsToFloat(t1.xyz);
    c.alpha = uintBitsToFloat(t0.w);
    c.thr = uintBitsToFloat(t1.w);
    c.flags = t2.z | (t2.y != 0u ? 8u : 0u);   // 8: an alpha image
    int rec = max(int(t2.y) - 1, 0);
    c.head = hs_mat(rec);
    c.lvl = hs_mat(rec + 1);
    return c;
}

// hs_transmittance of the material c was set up for.
float hs_cut_transmit(HsCut c, vec2 uv)
{
    if ((c.flags & HS_MAT_TRANSPARENT) == 0u) return 0.0;
    float a = c.alpha;
    if ((c.flags & 8u) != 0u) {
        vec3 p = vec3(uv, 1.0);
        vec4 s = hs_sample_rec(c.head, c.lvl, vec2(dot(c.r0, p), dot(c.r1, p)));
        vec3 rgb = c.head.w != 0u ? hs_srgb_decode(s.rgb) : s.rgb;
        a *= (c.flags & HS_MAT_LUMA) != 0u ? dot(rgb, vec3(0.2126, 0.7152, 0.0722)) : s.a;
    }
    if ((c.flags & HS_MAT_CLIP) != 0u) return a < c.thr ? 1.0 : 0.0;
    return clamp(1.0 - a, 0.0, 1.0);
}

// Whether a camera ray keeps the fragment (the G-buffer's cut): alpha >= 0.5 (BLEND) or the
// threshold (CLIP).
bool hs_alpha_keeps(int mat, vec2 uv)
{
    uvec4 t1 = hs_mat(HS_MAT_TEXELS * mat + 1);
    uvec4 t2 = hs_mat(HS_MAT_TEXELS * mat + 2);
    float thr = (t2.z & HS_MAT_CLIP) != 0u ? uintBitsToFloat(t1.w) : 0.5;
    return hs_material_alpha(mat, uv) >= thr;
}

// Stochastic transparency (core/gpu/see_through.py; oracle: core/oracle/alpha.py
// see_through_threshold). An integer hash (lowbias32) for the per-pixel, per-surface rotation.
uint hs_hash(uint x)
{
    x ^= x >> 16u; x *= 0x7feb352du;
    x ^= x >> 15u; x *= 0x846ca68bu;
    x ^= x >> 16u;
    return x;
}

// The threshold a BLEND fragment's alpha must exceed on sample s of a see-through accumulation:
// the bit-reversed sample index (van der Corput: any first 2^k samples stratify (0, 1)) rotated
// by a hash of the pixel (GL x, y) and the surface (instance index), so that pixels and stacked
// panes decorrelate; (2k + 1) / 2^24, exact in float32, strictly inside (0, 1).
float hs_alpha_threshold(uvec2 pixel, uint s, uint surface)
{
    uint r = hs_hash(hs_hash(hs_hash(surface + 0x9e3779b9u) ^ pixel.y) ^ pixel.x);
    uint t = bitfieldReverse(s) + r;
    return (float(t >> 9u) + 0.5) * (1.0 / 8388608.0);
}

// hs_alpha_keeps on sample s of a see-through accumulation (s < 0: none, the rule above): CLIP
// keeps its threshold; BLEND keeps the fragment where its alpha exceeds hs_alpha_threshold, so
// that over the samples a surface shows alpha of the time.
bool hs_alpha_keeps_sample(int mat, vec2 uv, int s, uvec2 pixel, uint surface)
{
    uvec4 t2 = hs_mat(HS_MAT_TEXELS * mat + 2);
    if (s < 0 || (t2.z & HS_MAT_CLIP) != 0u) return hs_alpha_keeps(mat, uv);
    return hs_material_alpha(mat, uv) > hs_alpha_threshold(pixel, uint(s), surface);
}

// Linear base colour factor of material mat's colour image at mesh UV uv and mip level lod
// (trilinear, Cubic images too), white without one.
vec3 hs_material_color(int mat, vec2 uv, float lod)
{
    uvec4 t2 = hs_mat(HS_MAT_TEXELS * mat + 2);
    if (t2.x == 0u) return vec3(1.0);
    int rec = int(t2.x) - 1;
    vec2 tuv = hs_material_uv(mat, uv);
    lod = max(lod, 0.0);
    int l0 = int(floor(lod));
    vec4 c = hs_sample_image(rec, tuv, l0, false);
    float f = lod - float(l0);
    if (f > 0.0) c = mix(c, hs_sample_image(rec, tuv, l0 + 1, false), f);
    return hs_image_srgb(rec) ? hs_srgb_decode(c.rgb) : c.rgb;
}

// Texel size of material mat's colour image (level 0), for the mip level; (1, 1) without one.
vec2 hs_material_color_size(int mat)
{
    uvec4 t2 = hs_mat(HS_MAT_TEXELS * mat + 2);
    if (t2.x == 0u) return vec2(1.0);
    uvec4 l0 = hs_mat(int(t2.x));
    return vec2(float(l0.w & 0xFFFFu), float(l0.w >> 16u));
}

#endif // HS_ALPHA_GLSL
