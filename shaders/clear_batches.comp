// Empty whole batches of a store that keeps every slot (a streamed cloud's evicted
// nodes): every word of the records of batches u_first.. (u_count / BATCH_SLOTS of
// them) EMPTY, wherever the record order keeps them (store_point's record_index), in
// one dispatch for a run of batches: in slot order their records lie in a slice a
// round, which took a clear call for each slice and word plane (160 a run).
layout(local_size_x = 256) in;
#include "common.glsl"
#include "points.glsl"

uniform uint u_first;       // the run's first batch
uniform uint u_count;       // the run's slots: its batches times BATCH_SLOTS
uniform uint u_batches;     // the permutation's batches

void main() {
    uint i;
    if (!range_index(u_count, i)) return;
    uint b = u_first + i / BATCH_SLOTS;
    uint within = i % BATCH_SLOTS;
    uint k = within / SLICE_POINTS;
    store_point(k * (u_batches * SLICE_POINTS) + b * SLICE_POINTS + (within - k * SLICE_POINTS), uvec4(EMPTY), -1);
}
