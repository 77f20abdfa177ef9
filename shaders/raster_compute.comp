// Compute rasterization of a range of shuffled slots into the visibility buffer.
// Each pixel keeps the point of least depth, ties to the least slot, as the 64-bit
// key (depth bits << 32 | slot): with ATOMIC64 one atomicMin per point, otherwise
// DEPTH_PASS (atomicMin of depth bits) then the index pass (least slot among points
// at exactly that depth). Positive float bits sort like the floats.
layout(local_size_x = 256) in;
#include "common.glsl"
#include "points.glsl"
#include "camera.glsl"
#include "sources.glsl"
#include "classes.glsl"

#if ATOMIC64
layout(std430, binding = BINDING_VISIBILITY) buffer Visibility { uint64_t visibility[]; };
#else
// word 2p: slot, word 2p+1: depth bits; byte-identical to the 64-bit key.
layout(std430, binding = BINDING_VISIBILITY) buffer Visibility { uint visibility[]; };
#endif

#if CULL
#include "batches.glsl"
#endif

void main() {
    uint i;
    if (!range_index(source_count(), i)) return;
    uint slot = source_slot(i);
#if CULL
    if (!slot_in_view(slot)) return;
#endif
    uvec4 record = source_record(i, slot);
    if (!finite_position(record) || !flags_shown(point_flags(slot, record.w))
        || !clip_keeps(uintBitsToFloat(record.xyz))) return;
    uint pixel;
    float depth;
    if (!project(uintBitsToFloat(record.xyz), pixel, depth)) return;
    uint depth_bits = floatBitsToUint(depth);
#if PARTITIONED
    // Points of one subgroup that hit one pixel (many, in a compact batch) meet first:
    // only the lane holding their least key (depth, then slot) goes on to the atomic.
#if ATOMIC64 || DEPTH_PASS
    uvec4 same = subgroupPartitionNV(pixel);
    uint least = subgroupPartitionedMinNV(depth_bits, same);
    if (subgroupPartitionedMinNV(depth_bits == least ? slot : EMPTY, same) != slot) return;
#else
    if (depth_bits != visibility[2u * pixel + 1u]) return;
    if (subgroupPartitionedMinNV(slot, subgroupPartitionNV(pixel)) != slot) return;
#endif
#endif
    // A reprojected point that improves its pixel leaves a hint (its list index), so
    // prepare can copy its record from the list; prepare validates it, races are harmless.
#if ATOMIC64
    uint64_t key = (uint64_t(depth_bits) << 32) | uint64_t(slot);
    if (key < visibility[pixel] && key < atomicMin(visibility[pixel], key)) {
#ifdef WRITE_HINT
        hint[pixel] = i;
#endif
    }
#elif DEPTH_PASS
    if (depth_bits < visibility[2u * pixel + 1u]) atomicMin(visibility[2u * pixel + 1u], depth_bits);
#else
    if (depth_bits == visibility[2u * pixel + 1u] && slot < visibility[2u * pixel]
        && slot < atomicMin(visibility[2u * pixel], slot)) {
#ifdef WRITE_HINT
        hint[pixel] = i;
#endif
    }
#endif
}
