// The paper's baseline: GL_POINTS with a hardware depth test. The pixel comes from
// the same project() as the compute rasterizer and the vertex sits at its centre, so
// sub-pixel snapping cannot move a point across a pixel edge; depth is linear in
// [near, far]. Rejected points are placed outside the clip volume.
#include "camera.glsl"

in vec3 a_position;
uniform uint u_chunk_base;   // slot of the chunk's first record
flat out uint v_slot;
flat out uint v_depth_bits;

void main() {
    v_slot = u_chunk_base + uint(gl_VertexID);
    gl_PointSize = 1.0;
    gl_Position = vec4(2.0, 2.0, 2.0, 1.0);
    uvec3 exponent = floatBitsToUint(a_position) & uvec3(0x7F800000u);
    uint pixel;
    float depth;
    if (any(equal(exponent, uvec3(0x7F800000u))) || !project(a_position, pixel, depth)) return;
    v_depth_bits = floatBitsToUint(depth);
    uint row = pixel / u_size.x;
    uint col = pixel - row * u_size.x;
    vec2 centre = (vec2(col, row) + 0.5) / vec2(u_size);
    float z = 2.0 * (depth - u_projection.z) / (u_projection.w - u_projection.z) - 1.0;
    gl_Position = vec4(centre.x * 2.0 - 1.0, 1.0 - centre.y * 2.0, z, 1.0);
}
