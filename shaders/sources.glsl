// Which slots a raster dispatch or draw covers. SOURCE_RANGE: a uniform range (whole
// cloud); SOURCE_PIECE: a fill piece placed on the GPU by budget.comp; SOURCE_LIST:
// last frame's visible slots appended by prepare.comp (reprojection).

#if SOURCE == SOURCE_RANGE
uniform uint u_first;
uniform uint u_count;
uint source_count() { return u_count; }
uint source_slot(uint i) { return u_first + i; }
#elif SOURCE == SOURCE_PIECE
layout(std430, binding = BINDING_FILL_STATE) readonly buffer FillState { uint fill_state[]; };
uniform uint u_piece;
uint source_count() { return fill_state[STATE_PIECES + 2u * u_piece + 1u]; }
uint source_slot(uint i) { return fill_state[STATE_PIECES + 2u * u_piece] + i; }
#else
layout(std430, binding = BINDING_SLOT_LIST) readonly buffer SlotList { uint slot_list[]; };
layout(std430, binding = BINDING_SLOT_LIST_META) readonly buffer SlotListMeta { uint list_meta[]; };
uniform uint u_capacity;
uint source_count() { return min(list_meta[0], u_capacity); }
uint source_slot(uint i) { return slot_list[i]; }
#endif
