// The batched layout's batches, and their culling flags written by cull.comp each frame.

uniform uint u_batches;

#if CULL
layout(std430, binding = BINDING_BATCH_FLAGS) readonly buffer Flags { uint batch_flags[]; };

bool batch_shown(uint b) {
    return batch_flags[b] != 0u;
}

// The batch whose slice holds a slot (progressive/permutation.py).
uint slot_batch(uint slot) {
    return (slot % (u_batches * SLICE_POINTS)) / SLICE_POINTS;
}

bool slot_in_view(uint slot) {
    return batch_shown(slot_batch(slot));
}
#endif
