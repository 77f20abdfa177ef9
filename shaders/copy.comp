// Bench reference: copy a buffer with a compute shader, 16 bytes an invocation, the
// way the rasterizers read the store (the driver's own buffer copy may use a slower
// copy engine). READ_ONLY: only read it (a write no value meets keeps the reads).
layout(local_size_x = 256) in;
#include "common.glsl"

layout(std430, binding = BINDING_DISTRIBUTE) readonly buffer Source { uvec4 source[]; };
layout(std430, binding = BINDING_COUNTERS) writeonly buffer Target { uvec4 target[]; };
uniform uint u_count;

void main() {
    uint i;
    if (!range_index(u_count, i)) return;
#if READ_ONLY
    uvec4 v = source[i];
    if (v == uvec4(u_count, 0x13579BDFu, 0x2468ACE0u, 0x0F1E2D3Cu)) target[0] = v;
#else
    target[i] = source[i];
#endif
}
