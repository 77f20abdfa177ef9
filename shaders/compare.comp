// Count the pixels whose visible slot equals the reference (brute-force) render's,
// on the GPU, so accuracy can be reported per frame without a readback.
layout(local_size_x = 16, local_size_y = 16) in;
#include "common.glsl"

#define VISIBILITY_ACCESS readonly
#include "visibility.glsl"
layout(std430, binding = BINDING_REFERENCE) readonly buffer Reference { uint reference[]; };
layout(std430, binding = BINDING_COUNTERS) buffer Counters { uint counters[]; };
uniform uvec2 u_size;

shared uint group_equal;

void main() {
    if (gl_LocalInvocationIndex == 0u) group_equal = 0u;
    barrier();
    uvec2 p = gl_GlobalInvocationID.xy;
    if (p.x < u_size.x && p.y < u_size.y) {
        uint pixel = p.y * u_size.x + p.x;
        if (visibility[2u * pixel] == reference[2u * pixel]) atomicAdd(group_equal, 1u);
    }
    barrier();
    if (gl_LocalInvocationIndex == 0u && group_equal > 0u) atomicAdd(counters[0], group_equal);
}
