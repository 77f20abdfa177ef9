// Scatter a staged batch into its permuted slots (paper section 3.3). With
// ATTRIBUTE_ONLY the stage holds one word per point and only word 3 is replaced; with
// CLASS_WORDS each point's 16 flag bits (class, first and last return) go to the store's flags.
layout(local_size_x = 256) in;
#include "common.glsl"
#include "points.glsl"

#if CLASS_WORDS
layout(std430, binding = BINDING_DISTRIBUTE) readonly buffer Stage { uint staged[]; };
layout(std430, binding = BINDING_CLASSES) buffer Classes { uint classes[]; };
#elif ATTRIBUTE_ONLY
layout(std430, binding = BINDING_DISTRIBUTE) readonly buffer Stage { uint staged[]; };
#else
layout(std430, binding = BINDING_DISTRIBUTE) readonly buffer Stage { uvec4 staged[]; };
#endif

uniform uint u_start;       // file-order index of staged[0]
uniform uint u_count;
uniform uint u_prime;
uniform uint u_rotation;
uniform uint u_batches;    // batched layout (0: one shuffle)
uniform uint u_capacity;    // slots held on the GPU: the rest of the cloud is left out

void main() {
    uint i;
    if (!range_index(u_count, i)) return;
    uint slot = slot_of(u_start + i, u_prime, u_rotation, u_batches);
    if (slot >= u_capacity) return;
#if CLASS_WORDS
    // Each slot is written once (the buffer starts at zero), two slots share a word.
    atomicOr(classes[slot >> 1u], (staged[i] & 0xFFFFu) << ((slot & 1u) * 16u));
#elif ATTRIBUTE_ONLY
    store_point(slot, uvec4(0u, 0u, 0u, staged[i]), 3);
#else
    store_point(slot, staged[i], -1);
#endif
}
