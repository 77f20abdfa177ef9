// Compute rasterization of a range of shuffled slots into the visibility buffer.
// Each pixel keeps the point of least depth, ties to the least slot, as the 64-bit
// key (depth bits << 32 | slot): with ATOMIC64 one atomicMin per point, otherwise
// DEPTH_PASS (atomicMin of depth bits) then the index pass (least slot among points
// at exactly that depth; with CANDIDATES, raster_candidates.comp over the depth pass's
// candidates instead, this one only where they overflowed). Positive float bits sort
// like the floats. WINNERS: the frame's last pass over the same points, after the
// visibility is final: the point its pixel kept writes its record there (winners.glsl),
// read while its batch is in cache, so prepare need not gather it from the store.
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
#include "improved.glsl"
#endif

#ifdef CANDIDATES
// The 32-bit path's depth pass lists its candidates (candidates.glsl), so that the index
// pass reads those instead of every point again; the index pass over the points runs
// only for a frame whose candidates overflowed.
#if DEPTH_PASS
#define CANDIDATES_ACCESS
#else
#define CANDIDATES_ACCESS readonly
#endif
#include "candidates.glsl"

#if DEPTH_PASS
void add_candidate(uint i, uint slot, uint pixel, uint depth_bits) {
    uint k = atomicAdd(candidate_meta[CANDIDATE_COUNT], 1u);
#if SOURCE == SOURCE_LIST
    uint listed = i;
#else
    uint listed = EMPTY;
#endif
    if (k < u_candidate_capacity) candidates[k] = uvec4(pixel, depth_bits, slot, listed);
}
#endif
#endif

// FILTERING: a hidden category, a return filter, a clip box or a section may leave a
// point out (ViewUniforms.filtering); a program without it has none of their tests. Not
// a uniform branch: llvmpipe runs every branch under a mask, so tests a uniform skipped
// still cost it their time on every point.

// One point into its pixel (source index i: the reprojection list's hint); record.xyz
// goes to view space as view_m · xyz + view_t: the camera's transform of a position
// relative to the origin (raster below), or a coarse batch's cells through its frame
// folded into that transform (the batch walk).
void raster_by(uint i, uint slot, uvec4 record, mat3 view_m, vec3 view_t) {
#if FILTERING
    if (!flags_shown(point_flags(slot, record.w)) || !clip_keeps(uintBitsToFloat(record.xyz))) return;
#endif
    uint pixel;
    float depth;
    // one test and one return: on llvmpipe an early return of its own costs every point
    if (!(project_view(view_m * uintBitsToFloat(record.xyz) + view_t, pixel, depth) && finite_position(record))) return;
#ifdef WINNERS
    if (visibility[2u * pixel] == slot) {
#if SOURCE == SOURCE_LIST
        winners[pixel] = record;
#else
        winners[pixel] = load_point(slot);      // all its words, as prepare would gather them
#endif
        WINNER_SLOT(pixel) = slot;
    }
#else
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
#ifdef IMPROVED
        mark_improved(slot);
#endif
    }
#elif DEPTH_PASS
#ifdef CANDIDATES
    uint held = visibility[2u * pixel + 1u];
    if (depth_bits < held) held = atomicMin(visibility[2u * pixel + 1u], depth_bits);
    if (depth_bits <= held) add_candidate(i, slot, pixel, depth_bits);
#else
    if (depth_bits < visibility[2u * pixel + 1u]) atomicMin(visibility[2u * pixel + 1u], depth_bits);
#endif
#else
    if (depth_bits == visibility[2u * pixel + 1u] && slot < visibility[2u * pixel]
        && slot < atomicMin(visibility[2u * pixel], slot)) {
#ifdef WRITE_HINT
        hint[pixel] = i;
#endif
#ifdef IMPROVED
        mark_improved(slot);
#endif
    }
#endif
#endif
}

void raster(uint i, uint slot, uvec4 record) {
    raster_by(i, slot, record, u_view_rotation, u_view_translation);
}

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
#if defined(CANDIDATES) && !DEPTH_PASS
    if (candidates_held()) return;
#endif
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
    mat3 view_m = u_view_rotation;
    vec3 view_t = u_view_translation;
#if !FILTERING
    // Below full precision (adaptive) a point's cells, exact as floats there, go to
    // view space in one multiply-add: the batch's frame is folded into the view
    // transform once a group, not decoded point by point. Exact batches keep the
    // decode the render contract's twins round alike; filters test decoded positions.
    if (levels < 3u) {
        view_m = u_view_rotation * mat3(frame_step.x, 0.0, 0.0, 0.0, frame_step.y, 0.0, 0.0, 0.0, frame_step.z);
        view_t = to_view(frame_base);
        frame_base = vec3(0.0);
        frame_step = vec3(1.0);
    }
#endif
#endif
    uint stride = u_batches * SLICE_POINTS;
    uint last = first + (count - 1u);
#ifdef VECTOR_WORDS
    // Where the batch's records lie together and aligned, or in slot order (a slice's
    // records then lie at its slots, aligned), each invocation takes four consecutive
    // records of a slice and loads each word plane's four words at once (the paper's
    // uvec4 prefetch): QUADS invocations a slice, SLICES_A_PASS slices a pass.
    const uint QUADS = SLICE_POINTS / 4u, SLICES_A_PASS = gl_WorkGroupSize.x / QUADS;
    uint block = batch_record(b);
    if (store_batches == 0u || quads_aligned(block, BATCH_SLOTS)) {
        uint lane = 4u * (gl_LocalInvocationID.x % QUADS);
        for (uint k = gl_LocalInvocationID.x / QUADS; k < ROUNDS; k += SLICES_A_PASS) {
            uint slot = k * stride + b * SLICE_POINTS + lane;   // of the first of the four
            if (slot > last) break;
            if (slot + 3u < first) continue;
            uint index = store_batches == 0u ? slot : block + k * SLICE_POINTS + lane;
            uvec4 w0, w1 = uvec4(0u), w2 = uvec4(0u), at = uvec4(EMPTY);
            if (slot >= first && slot + 3u <= last) {
                w0 = quad_words(0u, index);
                if (levels > 1u) w1 = quad_words(1u, index);
                if (levels > 2u) w2 = quad_words(2u, index);
                if (FILTERING != 0) at = quad_words(3u, index);
            } else {
                // A range that starts or ends inside these four: each record on its own.
                for (uint m = 0u; m < 4u; ++m) {
                    bool held = slot + m >= first && slot + m <= last;
                    uvec3 w = held ? point_words(index + m, levels) : uvec3(HIDDEN_WORD);
                    w0[m] = w.x; w1[m] = w.y; w2[m] = w.z;
                    at[m] = held && FILTERING != 0 ? attribute_word(index + m) : EMPTY;
                }
            }
            for (uint m = 0u; m < 4u; ++m)
                raster_by(slot + m, slot + m, uvec4(position_bits(uvec3(w0[m], w1[m], w2[m]), levels, frame_base, frame_step), at[m]),
                          view_m, view_t);
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
            attributes[j] = held && FILTERING != 0 ? attribute_word(index) : EMPTY;
#else
            loaded[j] = held ? load_record(index) : uvec4(EMPTY);
#endif
        }
        for (uint j = 0u; j < PREFETCH; ++j) {
#if WORD_PLANES
            raster_by(slots[j], slots[j], uvec4(position_bits(words[j], levels, frame_base, frame_step), attributes[j]),
                      view_m, view_t);
#else
            raster(slots[j], slots[j], loaded[j]);
#endif
        }
    }
}
#else
void main() {
    uint i;
    if (!range_index(source_count(), i)) return;
#if defined(CANDIDATES) && !DEPTH_PASS
    if (candidates_held()) return;
#endif
    uint slot = source_slot(i);
#if CULL
    if (!slot_in_view(slot)) return;
#endif
#if defined(IMPROVED) && defined(WINNERS)
    if (improved[slot_batch_of(slot)] == 0u) return;
#endif
    raster(i, slot, source_record(i, slot));
}
#endif
