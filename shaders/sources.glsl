// Which points a raster dispatch or draw covers. SOURCE_RANGE: a uniform slot range
// (whole cloud); SOURCE_PIECE: a fill piece placed on the GPU by budget.comp (both
// contiguous slot ranges: source_first, source_count);
// SOURCE_LIST: last frame's visible points, as record copies made by prepare.comp, so
// reprojection reads sequentially instead of gathering from the shuffled store.

#if SOURCE == SOURCE_RANGE
uniform uint u_first;
uniform uint u_count;
uint source_first() { return u_first; }
uint source_count() { return u_count; }
uint source_slot(uint i) { return u_first + i; }
uvec4 source_record(uint i, uint slot) { return load_point(slot); }
#elif SOURCE == SOURCE_PIECE
layout(std430, binding = BINDING_FILL_STATE) readonly buffer FillState { uint fill_state[]; };
uniform uint u_piece;
uint source_first() { return fill_state[STATE_PIECES + 2u * u_piece]; }
uint source_count() { return fill_state[STATE_PIECES + 2u * u_piece + 1u]; }
uint source_slot(uint i) { return source_first() + i; }
uvec4 source_record(uint i, uint slot) { return load_point(slot); }
#else
layout(std430, binding = BINDING_SLOT_LIST) readonly buffer SlotList { uint list_meta[META_WORDS]; uint slot_list[]; };
layout(std430, binding = BINDING_LIST_RECORDS) readonly buffer ListRecords { uvec4 list_records[]; };
uniform uint u_capacity;
uint source_count() { return min(list_meta[META_COUNT], u_capacity); }
uint source_slot(uint i) { return slot_list[i]; }
uvec4 source_record(uint i, uint slot) { return list_records[i]; }
#ifndef WINNERS
layout(std430, binding = BINDING_HINT) writeonly buffer Hint { uint hint[]; };
#define WRITE_HINT 1
#endif
#endif
