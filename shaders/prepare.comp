// Prepare (paper 3.4): every covered pixel's point becomes a record copy in the list
// the next frame reprojects, and its attribute word goes to the per-pixel words that
// resolve reads. With WINNERS the record comes from the raster's winners pass, which
// left each pixel's record where its point was drawn this frame (reprojected or
// filled); else from the current list when the pixel's hint points at the winning
// slot (a reprojected point). Any other point is gathered from the shuffled store (a
// point filled this frame without winners pass, a record the pass did not write; every
// point with REGATHER, after the store's attribute words were rewritten): random
// lookups into gigabytes cost a frame most, so as few as can be make them. One global
// atomicAdd per work group.
// With ARGS, a 1x1x1 dispatch turns the count into indirect arguments for the next
// reprojection (dispatch at word 1, draw at word 4). A list's meta words head its
// slot buffer: NVIDIA allows 16 storage blocks a shader and 8 hold the store.
#if ARGS
layout(local_size_x = 1) in;
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
}
#else
#include "points.glsl"
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
layout(std430, binding = BINDING_OUT_RECORDS) writeonly buffer OutRecords { uvec4 out_records[]; };
layout(std430, binding = BINDING_PIXEL_WORDS) writeonly buffer PixelWords { uint pixel_words[]; };
uniform uvec2 u_size;
uniform uint u_regather;

shared uint group_count;
shared uint group_gathers;
shared uint group_base;

void main() {
    if (gl_LocalInvocationIndex == 0u) {
        group_count = 0u;
        group_gathers = 0u;
    }
    barrier();
    uvec2 p = gl_GlobalInvocationID.xy;
    uint slot = EMPTY;
    uint pixel = 0u;
    uvec4 record = uvec4(0u);
    if (p.x < u_size.x && p.y < u_size.y) {
        pixel = p.y * u_size.x + p.x;
        slot = visibility[2u * pixel];
    }
    if (slot != EMPTY) {
#if WINNERS
        if (u_regather == 0u && WINNER_SLOT(pixel) == slot) {
            record = winners[pixel];
        } else {
#else
        uint h = hint[pixel];
        if (u_regather == 0u && h < min(prev_meta[META_COUNT], u_capacity) && prev_slots[h] == slot) {
            record = prev_records[h];
        } else {
#endif
            record = load_point(slot);
            atomicAdd(group_gathers, 1u);
        }
        pixel_words[pixel] = record.w;
    }
    uint local = slot != EMPTY ? atomicAdd(group_count, 1u) : 0u;
    barrier();
    if (gl_LocalInvocationIndex == 0u && group_count > 0u) {
        group_base = atomicAdd(out_meta[META_COUNT], group_count);
        atomicAdd(out_meta[META_GATHERS], group_gathers);
    }
    barrier();
    uint k = group_base + local;
    if (slot != EMPTY && k < u_capacity) {
        out_slots[k] = slot;
        out_records[k] = record;
    }
}
#endif
