// Buffer-less full-screen triangle: draw 3 vertices with no attributes.
// Include from the VERTEX_SHADER section; gives v_uv in 0..1 (uv (0,0) = bottom-left in GL).
out vec2 v_uv;
void main() {
    vec2 p = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));  // (0,0) (2,0) (0,2)
    v_uv = p;
    gl_Position = vec4(p * 2.0 - 1.0, 0.0, 1.0);
}
