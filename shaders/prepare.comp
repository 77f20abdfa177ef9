// Prepare (paper 3.4): append the slot of every covered pixel to the list that the
// next frame reprojects. One global atomicAdd per work group, not per pixel. With
// ARGS, a 1x1x1 dispatch turns the count into the next reprojection's indirect
// arguments (dispatch at word 1, draw at word 4).
#if ARGS
layout(local_size_x = 1) in;
#else
layout(local_size_x = 16, local_size_y = 16) in;
#endif
#include "common.glsl"

layout(std430, binding = BINDING_SLOT_LIST_META) buffer SlotListMeta { uint list_meta[]; };
uniform uint u_capacity;

#if ARGS
void main() {
    uint count = min(list_meta[0], u_capacity);
    uint groups = (count + 255u) / 256u;
    uint gx = min(groups, 65535u);
    list_meta[1] = gx;
    list_meta[2] = gx == 0u ? 0u : (groups + gx - 1u) / gx;
    list_meta[3] = 1u;
    list_meta[4] = count;
    list_meta[5] = 1u;
    list_meta[6] = 0u;
    list_meta[7] = 0u;
}
#else
layout(std430, binding = BINDING_VISIBILITY) readonly buffer Visibility { uint visibility[]; };
layout(std430, binding = BINDING_SLOT_LIST) writeonly buffer SlotList { uint slot_list[]; };
uniform uvec2 u_size;

shared uint group_count;
shared uint group_base;

void main() {
    if (gl_LocalInvocationIndex == 0u) group_count = 0u;
    barrier();
    uvec2 p = gl_GlobalInvocationID.xy;
    uint slot = EMPTY;
    if (p.x < u_size.x && p.y < u_size.y) slot = visibility[2u * (p.y * u_size.x + p.x)];
    uint local = slot != EMPTY ? atomicAdd(group_count, 1u) : 0u;
    barrier();
    if (gl_LocalInvocationIndex == 0u && group_count > 0u) group_base = atomicAdd(list_meta[0], group_count);
    barrier();
    uint k = group_base + local;
    if (slot != EMPTY && k < u_capacity) slot_list[k] = slot;
}
#endif
