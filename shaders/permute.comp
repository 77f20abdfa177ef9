// Map a list of file-order indices to shuffled slots in place: the GPU side of the
// permutation, checked against progressive/permutation.py.
layout(local_size_x = 256) in;
#include "common.glsl"

layout(std430, binding = BINDING_DISTRIBUTE) buffer Indices { uint indices[]; };
uniform uint u_count;
uniform uint u_prime;
uniform uint u_rotation;
uniform uint u_batches;    // batched layout (0: one shuffle)

void main() {
    uint i;
    if (!range_index(u_count, i)) return;
    indices[i] = slot_of(indices[i], u_prime, u_rotation, u_batches);
}
