// Compute rasterization of a range of shuffled slots into the visibility buffer.
// Each pixel keeps the point of least depth, ties to the least slot, as the 64-bit
// key (depth bits << 32 | slot): with ATOMIC64 one atomicMin per point, otherwise
// DEPTH_PASS (atomicMin of depth bits) then the index pass (least slot among points
// at exactly that depth). Positive float bits sort like the floats. WINNERS: the
// frame's last pass over the same points, after the visibility is final: the point
// its pixel kept writes its record there (winners.glsl), read while its batch is in
// cache, so prepare need not gather it from the store.
layout(local_size_x = 256) in;
#include "common.glsl"
#include "points.glsl"
#include "camera.glsl"
#include "sources.glsl"
#include "classes.glsl"

#ifdef WINNERS
#define VISIBILITY_ACCESS readonly
#define WINNERS_ACCESS writeonly
#include "winners.glsl"
#else
#if ATOMIC64
#define VISIBILITY_64
#endif
#define VISIBILITY_ACCESS
#endif
#include "visibility.glsl"

#if CULL || BATCH_GROUPS
#include "batches.glsl"
#endif

#ifdef IMPROVED
// Batches with a point that improved a pixel this frame: the winners pass walks only
// those, so a batch that no longer changes the image costs it one read. u_mark: 0 for
// brute force, which has no winners pass. Read before written, as the atomics are:
// the points of a batch's work group mostly find their batch marked already.
layout(std430, binding = BINDING_IMPROVED) buffer Improved { uint improved[]; };
uniform uint u_mark;

void mark_improved(uint slot) {
    uint b = slot_batch_of(slot);
    if (u_mark != 0u && improved[b] == 0u) improved[b] = 1u;
}
#endif

uniform uint u_filtering;    // 0: no filter can leave a point out (progressive/gpu.py filters_apply)

// A point on its way into its pixel: what each phase below needs of it.
struct Hit {
    uint i;             // source index (the reprojection list's hint)
    uint slot;
    uint pixel;
    uint depth_bits;
    bool live;          // still a candidate for its pixel
#if defined(WINNERS) && SOURCE == SOURCE_LIST
    uvec4 record;
#endif
};

// Its pixel and depth, live where it is finite, shown and in view.
Hit hit_of(uint i, uint slot, uvec4 record) {
    Hit h;
    h.i = i;
    h.slot = slot;
    h.pixel = 0u;
#if defined(WINNERS) && SOURCE == SOURCE_LIST
    h.record = record;
#endif
    float depth = 0.0;
    h.live = finite_position(record)
        && (u_filtering == 0u || (flags_shown(point_flags(slot, record.w)) && clip_keeps(uintBitsToFloat(record.xyz))))
        && project(uintBitsToFloat(record.xyz), h.pixel, depth);
    h.depth_bits = floatBitsToUint(depth);
    return h;
}

#if ATOMIC64
uint64_t key_of(Hit h) {
    return (uint64_t(h.depth_bits) << 32) | uint64_t(h.slot);
}
#endif

// The read: most points lose to what their pixel holds already and need no atomic
// (read before atomicMin). The winners pass: whether the pixel kept this point.
void test(inout Hit h) {
    if (!h.live) return;
#ifdef WINNERS
    h.live = visibility[2u * h.pixel] == h.slot;
#else
#if PARTITIONED
    // Points of one subgroup that hit one pixel (many, in a compact batch) meet first:
    // only the lane holding their least key (depth, then slot) goes on to the atomic.
#if ATOMIC64 || DEPTH_PASS
    uvec4 same = subgroupPartitionNV(h.pixel);
    uint least = subgroupPartitionedMinNV(h.depth_bits, same);
    if (subgroupPartitionedMinNV(h.depth_bits == least ? h.slot : EMPTY, same) != h.slot) { h.live = false; return; }
#else
    if (h.depth_bits != visibility[2u * h.pixel + 1u]) { h.live = false; return; }
    if (subgroupPartitionedMinNV(h.slot, subgroupPartitionNV(h.pixel)) != h.slot) { h.live = false; return; }
#endif
#endif
#if ATOMIC64
    h.live = key_of(h) < visibility[h.pixel];
#elif DEPTH_PASS
    h.live = h.depth_bits < visibility[2u * h.pixel + 1u];
#else
    h.live = h.depth_bits == visibility[2u * h.pixel + 1u] && h.slot < visibility[2u * h.pixel];
#endif
#endif
}

// The write: the atomic, live after it where the point improved its pixel. The
// winners pass writes the winner's record (all its words, as prepare would gather them).
void commit(inout Hit h) {
    if (!h.live) return;
#ifdef WINNERS
#if SOURCE == SOURCE_LIST
    winners[h.pixel] = h.record;
#else
    winners[h.pixel] = load_point(h.slot);
#endif
    WINNER_SLOT(h.pixel) = h.slot;
    h.live = false;
#elif ATOMIC64
    uint64_t key = key_of(h);
    h.live = key < atomicMin(visibility[h.pixel], key);
#elif DEPTH_PASS
    atomicMin(visibility[2u * h.pixel + 1u], h.depth_bits);
    h.live = false;
#else
    h.live = h.slot < atomicMin(visibility[2u * h.pixel], h.slot);
#endif
}

// What waits for the atomic's result. A reprojected point that improved its pixel
// leaves a hint (its list index), so prepare can copy its record from the list;
// prepare validates it, races are harmless.
void note(Hit h) {
    if (!h.live) return;
#ifdef WRITE_HINT
    hint[h.pixel] = h.i;
#endif
#if defined(IMPROVED) && !defined(WINNERS)
    mark_improved(h.slot);
#endif
}

// The points of one load (n of them, in hits) into their pixels. PHASED: phase by
// phase, every read, then every atomic, then what waits on their results, so that each
// phase's memory operations are in flight together. One point after another, a
// point's atomic waits for its read and the next point's read for that atomic (the
// same buffer, which the compiler cannot reorder).
#if PHASED
#define RASTER_HITS(hits, n) \
    for (uint j_ = 0u; j_ < (n); ++j_) test(hits[j_]); \
    for (uint j_ = 0u; j_ < (n); ++j_) commit(hits[j_]); \
    for (uint j_ = 0u; j_ < (n); ++j_) note(hits[j_]);
#else
#define RASTER_HITS(hits, n) \
    for (uint j_ = 0u; j_ < (n); ++j_) { test(hits[j_]); commit(hits[j_]); note(hits[j_]); }
#endif

#if BATCH_GROUPS
// One work group per batch over a contiguous slot range (brute force or a fill
// piece): the batch's slices are SLICE_POINTS consecutive slots every
// u_batches·SLICE_POINTS (progressive/permutation.py), and the group walks those in
// the range in turn, so the few pixels a compact batch covers stay in cache while
// its points go through (from one contiguous block of records where the store keeps
// batches together), and a culled batch costs its group one read. Each
// invocation loads PREFETCH records before it draws them, so that many reads are in
// flight while the atomics wait.
const uint ROUNDS = BATCH_SLOTS / SLICE_POINTS;

void main() {
    uint g = gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x;
    uint first = source_first(), count = source_count();
    if (count == 0u) return;
    // Group g takes the g-th batch whose slices meet the range: slice indices
    // first/SLICE_POINTS, ... belong to consecutive batches modulo u_batches (the
    // dispatch has one group for each, at most u_batches; budget.comp counts them).
    uint slice = first / SLICE_POINTS;
    if (g >= min(u_batches, (first + (count - 1u)) / SLICE_POINTS - slice + 1u)) return;
    uint b = (slice % u_batches + g) % u_batches;
#if CULL
    uint levels = batch_flags[b];   // 0: culled; else the position words to read (cull.comp)
    if (levels == 0u) return;
#else
    uint levels = 3u;
#endif
#if defined(IMPROVED) && defined(WINNERS)
    if (improved[b] == 0u) return;
#endif
#if WORD_PLANES
    vec3 frame_base = batch_frames[2u * b].xyz, frame_step = batch_frames[2u * b + 1u].xyz;
#endif
    uint stride = u_batches * SLICE_POINTS;
    uint last = first + (count - 1u);
#ifdef VECTOR_WORDS
    // Where the batch's records lie together and aligned, each invocation takes four
    // consecutive records of a slice and loads each word plane's four words at once
    // (the paper's uvec4 prefetch): QUADS invocations a slice, SLICES_A_PASS slices a pass.
    const uint QUADS = SLICE_POINTS / 4u, SLICES_A_PASS = gl_WorkGroupSize.x / QUADS;
    uint block = batch_record(b);
    if (store_batches != 0u && quads_aligned(block, BATCH_SLOTS)) {
        uint lane = 4u * (gl_LocalInvocationID.x % QUADS);
        for (uint k = gl_LocalInvocationID.x / QUADS; k < ROUNDS; k += SLICES_A_PASS) {
            uint slot = k * stride + b * SLICE_POINTS + lane;   // of the first of the four
            if (slot > last) break;
            if (slot + 3u < first) continue;
            uint index = block + k * SLICE_POINTS + lane;
            uvec4 w0, w1 = uvec4(0u), w2 = uvec4(0u), at = uvec4(EMPTY);
            if (slot >= first && slot + 3u <= last) {
                w0 = quad_words(0u, index);
                if (levels > 1u) w1 = quad_words(1u, index);
                if (levels > 2u) w2 = quad_words(2u, index);
                if (u_filtering != 0u) at = quad_words(3u, index);
            } else {
                // A range that starts or ends inside these four: each record on its own.
                for (uint m = 0u; m < 4u; ++m) {
                    bool held = slot + m >= first && slot + m <= last;
                    uvec3 w = held ? point_words(index + m, levels) : uvec3(HIDDEN_WORD);
                    w0[m] = w.x; w1[m] = w.y; w2[m] = w.z;
                    at[m] = held && u_filtering != 0u ? attribute_word(index + m) : EMPTY;
                }
            }
            Hit hits[4];
            for (uint m = 0u; m < 4u; ++m)
                hits[m] = hit_of(slot + m, slot + m, uvec4(position_bits(uvec3(w0[m], w1[m], w2[m]), levels, frame_base, frame_step), at[m]));
            RASTER_HITS(hits, 4u)
        }
        return;
    }
#endif
    uint base = b * SLICE_POINTS + gl_LocalInvocationID.x;
    // The batch's records: one contiguous block (RecordOrder.BATCHES), else in slot order.
    uint records = store_batches == 0u ? base : batch_record(b) + gl_LocalInvocationID.x;
    uint record_stride = store_batches == 0u ? stride : SLICE_POINTS;
    uint k = first > base ? (first - base + stride - 1u) / stride : 0u;
    for (; k < ROUNDS && base + k * stride <= last; k += PREFETCH) {
        uint slots[PREFETCH];
#if WORD_PLANES
        uvec3 words[PREFETCH];
        uint attributes[PREFETCH];
#else
        uvec4 loaded[PREFETCH];
#endif
        for (uint j = 0u; j < PREFETCH; ++j) {
            // k + j < ROUNDS first: past the last round the product could wrap around.
            slots[j] = k + j < ROUNDS ? base + (k + j) * stride : EMPTY;
            uint index = records + (k + j) * record_stride;
            bool held = slots[j] <= last;
#if WORD_PLANES
            // Every word is loaded before any is decoded; the attribute word only where a
            // filter reads it (a category's code).
            words[j] = held ? point_words(index, levels) : uvec3(HIDDEN_WORD);
            attributes[j] = held && u_filtering != 0u ? attribute_word(index) : EMPTY;
#else
            loaded[j] = held ? load_record(index) : uvec4(EMPTY);
#endif
        }
        Hit hits[PREFETCH];
        for (uint j = 0u; j < PREFETCH; ++j) {
#if WORD_PLANES
            hits[j] = hit_of(slots[j], slots[j], uvec4(position_bits(words[j], levels, frame_base, frame_step), attributes[j]));
#else
            hits[j] = hit_of(slots[j], slots[j], loaded[j]);
#endif
        }
        RASTER_HITS(hits, PREFETCH)
    }
}
#else
void main() {
    uint i;
    if (!range_index(source_count(), i)) return;
    uint slot = source_slot(i);
#if CULL
    if (!slot_in_view(slot)) return;
#endif
#if defined(IMPROVED) && defined(WINNERS)
    if (improved[slot_batch_of(slot)] == 0u) return;
#endif
    Hit hits[1] = Hit[1](hit_of(i, slot, source_record(i, slot)));
    RASTER_HITS(hits, 1u)
}
#endif
