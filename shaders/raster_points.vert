// The paper's baseline: GL_POINTS with a hardware depth test. The pixel comes from
// the same project() as the compute rasterizer and the vertex sits at its centre, so
// sub-pixel snapping cannot move a point across a pixel edge; depth is linear in
// [near, far]. Rejected points are placed outside the clip volume. Every draw pulls
// its points from the same sources as the compute rasterizer, by gl_VertexID in slot
// order, so the depth test's first-drawn wins is the contract's least slot.
#define VERTEX_STAGE 1
#include "common.glsl"
#include "points.glsl"
#include "sources.glsl"
#include "camera.glsl"
#include "classes.glsl"

flat out uint v_slot;
flat out uint v_depth_bits;

void main() {
    gl_PointSize = 1.0;
    gl_Position = vec4(2.0, 2.0, 2.0, 1.0);
    uint i = uint(gl_VertexID);
    if (i >= source_count()) return;
    v_slot = source_slot(i);
    uvec4 record = source_record(i, v_slot);
    uint pixel;
    float depth;
    if (!finite_position(record) || !flags_shown(point_flags(v_slot, record.w)) || !clip_keeps(uintBitsToFloat(record.xyz))
        || !project(uintBitsToFloat(record.xyz), pixel, depth)) return;
    v_depth_bits = floatBitsToUint(depth);
    uint row = pixel / u_size.x;
    uint col = pixel - row * u_size.x;
    vec2 centre = (vec2(col, row) + 0.5) / vec2(u_size);
    float z = 2.0 * (depth - u_projection.z) / (u_projection.w - u_projection.z) - 1.0;
    gl_Position = vec4(centre.x * 2.0 - 1.0, 1.0 - centre.y * 2.0, z, 1.0);
}
