// The batched layout's per-batch culling flags, written by cull.comp each frame.

layout(std430, binding = BINDING_BATCH_FLAGS) readonly buffer Flags { uint batch_flags[]; };
uniform uint u_batches;

// The batch whose slice holds a slot (progressive/permutation.py).
uint slot_batch(uint slot) {
    return (slot % (u_batches * SLICE_POINTS)) / SLICE_POINTS;
}

bool slot_in_view(uint slot) {
    return batch_flags[slot_batch(slot)] != 0u;
}
