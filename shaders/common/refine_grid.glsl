// The coarse sample grid of the refinement passes: sample q stands at full-resolution pixel
// q * u_scale + u_offset (clamped to the image, as mask_source_pixel); its value is u_coarse at
// q, or (HS_INTERLACE) u_coarse at that pixel: the interlaced trace of this frame, where texels
// >= 0 are final and -1 marks those without a ray or history.

uniform sampler2D u_coarse;
uniform int u_scale;            // spacing of the coarse samples (full-resolution pixels)
uniform ivec2 u_offset;         // position of sample (0, 0)
uniform ivec2 u_full_size;

ivec2 sample_pixel(ivec2 q) { return min(q * u_scale + u_offset, u_full_size - 1); }

ivec2 sample_grid()             // samples per axis
{
#ifdef HS_INTERLACE
    return (u_full_size - u_offset + u_scale - 1) / u_scale;
#else
    return textureSize(u_coarse, 0);
#endif
}

float sample_value(ivec2 q)
{
#ifdef HS_INTERLACE
    return texelFetch(u_coarse, sample_pixel(q), 0).r;
#else
    return texelFetch(u_coarse, q, 0).r;
#endif
}

// The cell of pixel px: its 2x2 surrounding samples are cell + (0|1, 0|1).
ivec2 sample_cell(ivec2 px) { return ivec2(floor(vec2(px - u_offset) / float(u_scale))); }
