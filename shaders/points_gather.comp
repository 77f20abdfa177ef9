// Copy the GL_POINTS attachments (row 0 at the bottom) into the visibility buffer
// (row 0 at the top), so resolve and readback do not depend on the rasterizer.
layout(local_size_x = 16, local_size_y = 16) in;
#include "common.glsl"

#define VISIBILITY_ACCESS writeonly
#include "visibility.glsl"
uniform usampler2D u_slots;
uniform usampler2D u_depths;
uniform uvec2 u_size;

void main() {
    uvec2 p = gl_GlobalInvocationID.xy;
    if (p.x >= u_size.x || p.y >= u_size.y) return;
    ivec2 texel = ivec2(p.x, u_size.y - 1u - p.y);
    uint pixel = p.y * u_size.x + p.x;
    visibility[2u * pixel] = texelFetch(u_slots, texel, 0).r;
    visibility[2u * pixel + 1u] = texelFetch(u_depths, texel, 0).r;
}
