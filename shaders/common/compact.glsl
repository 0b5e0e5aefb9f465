// A compacted list of the pixels that need a ray, read from a histogram pyramid (Ziegler et al.
// 2006, "On-the-fly point clouds through histogram pyramids"): level 0 (u_need, full resolution)
// holds 1 per pixel that needs a ray, each level above sums 2x2 texels of the one below; the top
// (1x1, level u_levels - 1) is the count. Levels 1 and up live in two atlases, alternating from
// the top: the top in u_pyr0, the level below it in u_pyr1, the next in u_pyr0, and so on;
// u_lvl_off / u_lvl_size give each level's place (level 0 at (0, 0) of u_need).
// The list is in the pyramid's quadtree order (neighbouring entries, neighbouring pixels);
// entry k sits in the compact target at compact_texel(k): 16 consecutive entries per 4x4 block.

uniform sampler2D u_need;
uniform sampler2D u_pyr0;
uniform sampler2D u_pyr1;
uniform int u_levels;
uniform ivec2 u_lvl_off[16];
uniform ivec2 u_lvl_size[16];
uniform int u_compact_width;    // multiple of 4

float pyr_count(sampler2D s, int level, ivec2 c)
{
    return all(lessThan(c, u_lvl_size[level])) ? texelFetch(s, u_lvl_off[level] + c, 0).r : 0.0;
}

int compact_total()
{
    float n = u_levels == 1 ? texelFetch(u_need, ivec2(0), 0).r : texelFetch(u_pyr0, u_lvl_off[u_levels - 1], 0).r;
    return int(n + 0.5);
}

int compact_index(ivec2 ct)
{
    return ((ct.y >> 2) * (u_compact_width >> 2) + (ct.x >> 2)) * 16 + ((ct.y & 3) << 2) + (ct.x & 3);
}

ivec2 compact_texel(int k)
{
    int block = k >> 4, r = k & 15;
    int bw = u_compact_width >> 2;
    return ivec2((block % bw) * 4 + (r & 3), (block / bw) * 4 + (r >> 2));
}

// One step down: the child of pos at 'level' that holds entry kf (kf becomes its rank there).
void hs_find_step(sampler2D s, int level, inout ivec2 pos, inout float kf)
{
    ivec2 b = pos * 2;
    float c0 = pyr_count(s, level, b), c1 = pyr_count(s, level, b + ivec2(1, 0));
    float c2 = pyr_count(s, level, b + ivec2(0, 1));
    if (kf < c0) { pos = b; }
    else if (kf < c0 + c1) { pos = b + ivec2(1, 0); kf -= c0; }
    else if (kf < c0 + c1 + c2) { pos = b + ivec2(0, 1); kf -= c0 + c1; }
    else { pos = b + ivec2(1, 1); kf -= c0 + c1 + c2; }
}

// The pixel of entry k (0 <= k < compact_total()).
ivec2 compact_find(int k)
{
    ivec2 pos = ivec2(0);
    float kf = float(k);
    for (int i = u_levels - 2; i >= 1; i -= 2) {
        hs_find_step(u_pyr1, i, pos, kf);
        if (i >= 2) hs_find_step(u_pyr0, i - 1, pos, kf);
    }
    if (u_levels > 1) hs_find_step(u_need, 0, pos, kf);
    return pos;
}

// The entry of pixel px (which needs a ray): the count of the entries before it.
// Adds the entries of the quadrants before px's at 'level' (its siblings in the pyramid's order).
void hs_prefix_step(sampler2D s, int level, ivec2 px, inout float idx)
{
    ivec2 c = px >> level;
    ivec2 b = c & ~1;
    int o = (c.x & 1) + 2 * (c.y & 1);
    if (o > 0) idx += pyr_count(s, level, b);
    if (o > 1) idx += pyr_count(s, level, b + ivec2(1, 0));
    if (o > 2) idx += pyr_count(s, level, b + ivec2(0, 1));
}

int compact_prefix(ivec2 px)
{
    float idx = 0.0;
    for (int i = u_levels - 2; i >= 1; i -= 2) {
        hs_prefix_step(u_pyr1, i, px, idx);
        if (i >= 2) hs_prefix_step(u_pyr0, i - 1, px, idx);
    }
    if (u_levels > 1) hs_prefix_step(u_need, 0, px, idx);
    return int(idx + 0.5);
}
