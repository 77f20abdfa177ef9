// Prepare (paper 3.4): every covered pixel's point becomes a record copy in the list
// the next frame reprojects, and its attribute word goes to the per-pixel words that
// resolve reads. With WINNERS the record comes from the raster's winners pass, which
// left each pixel's record where its point was drawn this frame (reprojected or
// filled); else from the current list when the pixel's hint points at the winning
// slot (a reprojected point). Any other point is gathered from the shuffled store (a
// point filled this frame without winners pass, a record the pass did not write; every
// point with REGATHER, after the store's attribute words were rewritten): random
// lookups into gigabytes cost a frame most, so as few as can be make them.
//
// Three dispatches. The pixels' pass lists every covered pixel's slot and copies the
// records it has; the pixels it cannot fill go to a list of gathers. ARGS (1x1x1) turns
// the counts into indirect arguments: the next reprojection's (dispatch at word 1, draw
// at word 4) and the gathers' (word 9). GATHER reads those records from the store, one
// invocation each, so its vectors of invocations are whole: llvmpipe runs a branch any
// lane takes for all lanes, so gathers scattered among the pixels made most vectors
// run the store's decoding. A list's meta words head its slot buffer: NVIDIA allows
// 16 storage blocks a shader and 8 hold the store.
#if ARGS
layout(local_size_x = 1) in;
#elif GATHER
layout(local_size_x = 256) in;
#else
layout(local_size_x = 16, local_size_y = 16) in;
#endif
#include "common.glsl"

layout(std430, binding = BINDING_OUT_SLOTS) buffer OutSlots { uint out_meta[META_WORDS]; uint out_slots[]; };
uniform uint u_capacity;

#if ARGS
void main() {
    uint count = min(out_meta[META_COUNT], u_capacity);
    uvec3 grid = dispatch_grid(count);
    out_meta[META_DISPATCH] = grid.x;
    out_meta[META_DISPATCH + 1] = grid.y;
    out_meta[META_DISPATCH + 2] = grid.z;
    out_meta[META_DRAW] = count;
    out_meta[META_DRAW + 1] = 1u;
    out_meta[META_DRAW + 2] = 0u;
    out_meta[META_DRAW + 3] = 0u;
    uvec3 gathers = dispatch_grid(min(out_meta[META_GATHERS], u_capacity));
    out_meta[META_GATHER_DISPATCH] = gathers.x;
    out_meta[META_GATHER_DISPATCH + 1] = gathers.y;
    out_meta[META_GATHER_DISPATCH + 2] = gathers.z;
}
#else
// Each gather: the list entry it fills and its pixel.
layout(std430, binding = BINDING_GATHERS) buffer Gathers { uvec2 gathers[]; };
layout(std430, binding = BINDING_OUT_RECORDS) writeonly buffer OutRecords { uvec4 out_records[]; };
layout(std430, binding = BINDING_PIXEL_WORDS) writeonly buffer PixelWords { uint pixel_words[]; };

#if GATHER
#include "points.glsl"

void main() {
    uint i;
    if (!range_index(min(out_meta[META_GATHERS], u_capacity), i)) return;
    uvec2 gather = gathers[i];
    if (gather.x >= u_capacity) return;
    uvec4 record = load_point(out_slots[gather.x]);
    out_records[gather.x] = record;
    pixel_words[gather.y] = record.w;
}
#else
#define VISIBILITY_ACCESS readonly
#include "visibility.glsl"
#if WINNERS
#define WINNERS_ACCESS readonly
#include "winners.glsl"
#else
layout(std430, binding = BINDING_SLOT_LIST) readonly buffer PrevSlots { uint prev_meta[META_WORDS]; uint prev_slots[]; };
layout(std430, binding = BINDING_LIST_RECORDS) readonly buffer PrevRecords { uvec4 prev_records[]; };
layout(std430, binding = BINDING_HINT) readonly buffer Hint { uint hint[]; };
#endif
uniform uvec2 u_size;
uniform uint u_regather;

#if BALLOT
// Entries of out_meta[WORD]'s list for the invocations of a subgroup that take one, in
// one atomicAdd and no barrier (llvmpipe runs a work group that meets at a barrier as
// coroutines; bench.progressive --prepare compares both). Every invocation of the
// subgroup runs it; `index` is set where `take`.
#define TAKE_ENTRY(WORD, take, index) {                                                    \
        uvec2 taking = unpackUint2x32(ballotARB(take));                                \
        uvec2 below = unpackUint2x32(gl_SubGroupLtMaskARB) & taking;                   \
        uint total = bitCount(taking.x) + bitCount(taking.y);                          \
        if (total > 0u) {                                                              \
            uint first = taking.x != 0u ? uint(findLSB(taking.x)) : 32u + uint(findLSB(taking.y)); \
            uint base = 0u;                                                            \
            if (gl_SubGroupInvocationARB == first) base = atomicAdd(out_meta[WORD], total); \
            index = readInvocationARB(base, first) + bitCount(below.x) + bitCount(below.y); \
        }                                                                              \
    }
#else
shared uint group_count;
shared uint group_gathers;
shared uint group_base;
shared uint group_gather_base;
#endif

void main() {
#if !BALLOT
    if (gl_LocalInvocationIndex == 0u) {
        group_count = 0u;
        group_gathers = 0u;
    }
    barrier();
#endif
    uvec2 p = gl_GlobalInvocationID.xy;
    uint pixel = 0u;
    uint slot = EMPTY;
    if (p.x < u_size.x && p.y < u_size.y) {
        pixel = p.y * u_size.x + p.x;
        slot = visibility[2u * pixel];
    }
    bool covered = slot != EMPTY;
    bool gather = covered;
    uvec4 record = uvec4(0u);
    if (covered && u_regather == 0u) {
#if WINNERS
        if (WINNER_SLOT(pixel) == slot) {
            record = winners[pixel];
            gather = false;
        }
#else
        uint h = hint[pixel];
        if (h < min(prev_meta[META_COUNT], u_capacity) && prev_slots[h] == slot) {
            record = prev_records[h];
            gather = false;
        }
#endif
    }
    uint k = 0u, g = 0u;
#if BALLOT
    TAKE_ENTRY(META_COUNT, covered, k)
    TAKE_ENTRY(META_GATHERS, gather, g)
#else
    uint local = covered ? atomicAdd(group_count, 1u) : 0u;
    uint local_gather = gather ? atomicAdd(group_gathers, 1u) : 0u;
    barrier();
    if (gl_LocalInvocationIndex == 0u) {
        group_base = group_count > 0u ? atomicAdd(out_meta[META_COUNT], group_count) : 0u;
        group_gather_base = group_gathers > 0u ? atomicAdd(out_meta[META_GATHERS], group_gathers) : 0u;
    }
    barrier();
    k = group_base + local;
    g = group_gather_base + local_gather;
#endif
    if (gather) gathers[g] = uvec2(k, pixel);
    if (covered && k < u_capacity) {
        out_slots[k] = slot;
        if (!gather) {
            out_records[k] = record;
            pixel_words[pixel] = record.w;
        }
    }
}
#endif
#endif
