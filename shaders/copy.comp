// Bench reference: copy a buffer with a compute shader, 16 bytes an invocation, the
// way the rasterizers read the store (the driver's own buffer copy may use a slower
// copy engine).
layout(local_size_x = 256) in;
#include "common.glsl"

layout(std430, binding = BINDING_DISTRIBUTE) readonly buffer Source { uvec4 source[]; };
layout(std430, binding = BINDING_COUNTERS) writeonly buffer Target { uvec4 target[]; };
uniform uint u_count;

void main() {
    uint i;
    if (!range_index(u_count, i)) return;
    target[i] = source[i];
}
