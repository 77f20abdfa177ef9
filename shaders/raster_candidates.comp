// The 32-bit raster's index pass over the depth pass's candidates (candidates.glsl):
// each pixel keeps the least slot among its candidates at its final depth, as the index
// pass over the points would, reading 16 bytes a candidate in order instead of every
// point's words, decoded and projected again. ARGS: one invocation writes this pass's
// dispatch arguments from the count, and those of the index pass over the points of the
// frame's fill pieces (FALLBACK_PIECES: their walk's or one invocation a slot's, from
// u_piece_args in the budget pass's) and its list (FALLBACK_LIST): theirs where the
// candidates overflowed, else no work group.
layout(local_size_x = 256) in;
#include "common.glsl"
#define CANDIDATES_ACCESS
#include "candidates.glsl"

#ifdef ARGS
#ifdef FALLBACK_PIECES
layout(std430, binding = BINDING_FILL_ARGS) readonly buffer FillArgs { uint fill_args[]; };
uniform uint u_piece_args;
#endif
#ifdef FALLBACK_LIST
layout(std430, binding = BINDING_SLOT_LIST) readonly buffer SlotList { uint list_meta[META_WORDS]; };
#endif

void main() {
    bool held = candidates_held();
    uvec3 groups = dispatch_grid(min(candidate_meta[CANDIDATE_COUNT], u_candidate_capacity));
    for (uint k = 0u; k < 3u; ++k) {
        candidate_meta[CANDIDATE_DISPATCH + k] = groups[k];
#ifdef FALLBACK_PIECES
        for (uint piece = 0u; piece < FILL_PIECES; ++piece)
            candidate_meta[CANDIDATE_FALLBACK + 3u * piece + k] = held ? 0u : fill_args[u_piece_args + 3u * piece + k];
#endif
#ifdef FALLBACK_LIST
        candidate_meta[CANDIDATE_FALLBACK + 3u * FILL_PIECES + k] = held ? 0u : list_meta[META_DISPATCH + k];
#endif
    }
}
#else
#define VISIBILITY_ACCESS
#include "visibility.glsl"
#ifdef IMPROVED
#include "records.glsl"
#include "improved.glsl"
#endif
#ifdef HINTS
layout(std430, binding = BINDING_HINT) writeonly buffer Hint { uint hint[]; };
#endif

void main() {
    uint k;
    if (!range_index(min(candidate_meta[CANDIDATE_COUNT], u_candidate_capacity), k)) return;
    uvec4 c = candidates[k];
    uint pixel = c.x, slot = c.z, held = visibility[2u * pixel];
    if (c.y != visibility[2u * pixel + 1u] || slot > held) return;
    uint old = slot < held ? atomicMin(visibility[2u * pixel], slot) : held;
    // A reprojected point that holds the pixel leaves its list index (as sources.glsl's
    // WRITE_HINT), also where the same slot's copy from a fill piece, drawn in the same
    // frame, came first (the index pass over the points drew the list first); a slot of
    // the store that improved the pixel marks its batch.
#ifdef HINTS
    if (c.w != EMPTY && slot <= old) hint[pixel] = c.w;
#endif
#ifdef IMPROVED
    if (c.w == EMPTY && slot < old) mark_improved(slot);
#endif
}
#endif
