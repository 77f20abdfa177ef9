// Counts for the exact percentile select (progressive/quantiles.py). LEVEL 0 counts
// the high 16 bits of the order key of every drawn point's value; LEVEL 1 counts the
// low 16 bits of the keys whose high half is one of u_targets, a row per target.
layout(local_size_x = 256) in;
#include "common.glsl"
#include "points.glsl"

layout(std430, binding = BINDING_HISTOGRAM) buffer Counts { uint counts[]; };
uniform uint u_count;
uniform uvec4 u_targets;

// Unsigned keys that order like the float32 values (quantiles.order_keys).
uint order_key(uint bits) {
    return (bits & 0x80000000u) != 0u ? ~bits : bits | 0x80000000u;
}

void main() {
    uint slot;
    if (!range_index(u_count, slot)) return;
    uvec4 record = load_point(slot);
    if (!finite_position(record) || (record.w & 0x7F800000u) == 0x7F800000u) return;
    uint key = order_key(record.w);
    uint high = key >> 16;
#if LEVEL == 0
    atomicAdd(counts[high], 1u);
#else
    for (uint j = 0u; j < 4u; ++j) {
        if (high == u_targets[j]) atomicAdd(counts[j * 65536u + (key & 0xFFFFu)], 1u);
    }
#endif
}
