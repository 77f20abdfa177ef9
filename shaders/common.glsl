// Shared helpers: dispatch indexing, the exact prime permutation, sentinels.

const uint EMPTY = 0xFFFFFFFFu;

// Empty slots and non-finite coordinates are never drawn.
bool finite_position(uvec4 record) {
    uvec3 exponent = record.xyz & uvec3(0x7F800000u);
    return all(notEqual(exponent, uvec3(0x7F800000u)));
}

#ifndef VERTEX_STAGE
// Invocation i of a 1-D range spread over a 2-D grid of 1-D work groups (GL only
// guarantees 65535 groups per dimension). False past `count`; never overflows.
bool range_index(uint count, out uint i) {
    uint group = gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x;
    if (count == 0u || group > (count - 1u) / gl_WorkGroupSize.x) return false;
    uint base = group * gl_WorkGroupSize.x;
    if (gl_LocalInvocationID.x >= count - base) return false;
    i = base + gl_LocalInvocationID.x;
    return true;
}
#endif

#ifdef RANGE_GROUP
// Indirect dispatch arguments for `count` invocations of range_index in work groups of
// RANGE_GROUP: the twin of progressive/gpu.py grid(), except that 0 gives 0 groups.
uvec3 dispatch_groups(uint groups) {
    uint gx = min(groups, GUARANTEED_GROUPS);
    return uvec3(gx, gx == 0u ? 0u : (groups + gx - 1u) / gx, 1u);
}

uvec3 dispatch_grid(uint count) {
    return dispatch_groups((count + RANGE_GROUP - 1u) / RANGE_GROUP);
}
#endif

#ifdef PERMUTE_INT64
uint mulmod(uint a, uint b, uint p) {
    return uint((uint64_t(a) * uint64_t(b)) % uint64_t(p));
}
#else
// a*b mod p with 32-bit words only: the high word is < p because a, b < p, then the
// low word is shifted in one bit at a time, subtracting p whenever the value reaches it.
uint mulmod(uint a, uint b, uint p) {
    if (p <= 0xFFFFu) return a * b % p;
    uint hi, lo;
    umulExtended(a, b, hi, lo);
    uint r = hi;
    for (int bit = 31; bit >= 0; --bit) {
        uint carry = r >> 31;
        r = (r << 1) | ((lo >> uint(bit)) & 1u);
        if (carry != 0u || r >= p) r -= p;
    }
    return r;
}
#endif

uint quadratic_residue(uint x, uint p) {
    uint r = mulmod(x, x, p);
    return x <= p / 2u ? r : p - r;
}

// File-order index -> shuffled slot; indices >= prime stay (progressive/permutation.py).
uint permute(uint i, uint prime, uint rotation) {
    if (i >= prime) return i;
    uint x = quadratic_residue(i, prime);
    x = x >= prime - rotation ? x - (prime - rotation) : x + rotation;
    return quadratic_residue(x, prime);
}

// The batched layout's shuffle of a batch's local index (< BATCH_POINTS, the prime):
// the same double quadratic residue, with the prime a constant below 2^16, so every
// product fits 32 bits and each remainder compiles to multiplications.
uint batch_residue(uint x) {
    uint r = x * x % BATCH_POINTS;
    return x <= BATCH_POINTS / 2u ? r : BATCH_POINTS - r;
}

uint batch_shuffle(uint local, uint b, uint rotation) {
    uint r = (b + 1u) % BATCH_POINTS * rotation % BATCH_POINTS;
    uint x = batch_residue(local);
    x = x >= BATCH_POINTS - r ? x - (BATCH_POINTS - r) : x + r;
    return batch_residue(x);
}

// File-order index -> slot of the layout (progressive/permutation.py Permutation):
// batches == 0: one shuffle of the whole cloud; else batch b = i / BATCH_POINTS is
// shuffled inside itself (rotation offset·(b+1) mod P, P = BATCH_POINTS) and stored in
// slices of SLICE_POINTS, slice k of every batch before slice k+1 of any.
uint slot_of(uint i, uint prime, uint rotation, uint batches) {
    if (batches == 0u) return permute(i, prime, rotation);
    uint b = i / BATCH_POINTS;
    uint shuffled = batch_shuffle(i - b * BATCH_POINTS, b, rotation);
    uint piece = shuffled / SLICE_POINTS;
    return piece * (batches * SLICE_POINTS) + b * SLICE_POINTS + (shuffled - piece * SLICE_POINTS);
}
