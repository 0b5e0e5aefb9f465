// G-buffer inputs of the full-screen passes (texelFetch only: nearest, exact).
uniform sampler2D u_gb_position;   // world xyz, w = 1 on geometry, 0 on background
uniform sampler2D u_gb_normal;     // unit geometric normal facing the camera; w as position's
uniform sampler2D u_gb_shading;    // shading normal (turned over with the geometric one)
uniform sampler2D u_gb_albedo;     // linear base colour
uniform sampler2D u_gb_material;   // specular, roughness, instance index
uniform sampler2D u_gb_terminator; // xyz: smooth-surface lift (world), w: geometry offset; 0: flat
uniform sampler2D u_gb_depth;      // view depth (metres), 0 on background

// The full-resolution pixel a reduced-resolution mask texel stands for.
ivec2 mask_source_pixel(ivec2 mask_texel, int scale, ivec2 full_size) {
    return min(mask_texel * scale + scale / 2, full_size - 1);
}
