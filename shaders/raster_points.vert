// The paper's baseline: GL_POINTS with a hardware depth test. Clip z is linear in
// depth, so the clip volume is exactly near <= depth <= far (the render contract).
#include "camera.glsl"

in vec3 a_position;
uniform uint u_chunk_base;   // slot of the chunk's first record
flat out uint v_slot;
flat out uint v_depth_bits;

void main() {
    v_slot = u_chunk_base + uint(gl_VertexID);
    uvec3 bits = floatBitsToUint(a_position) & uvec3(0x7F800000u);
    vec3 v = to_view(a_position);
    float depth = -v.z;
    v_depth_bits = floatBitsToUint(depth);
    float z = 2.0 * (depth - u_projection.z) / (u_projection.w - u_projection.z) - 1.0;
    gl_Position = vec4(u_projection.x * v.x, u_projection.y * v.y, z * depth, depth);
    if (any(equal(bits, uvec3(0x7F800000u)))) gl_Position = vec4(2.0, 2.0, 2.0, 1.0);
    gl_PointSize = 1.0;
}
