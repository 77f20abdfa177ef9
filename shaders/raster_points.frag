flat in uint v_slot;
flat in uint v_depth_bits;
layout(location = 0) out uint o_slot;
layout(location = 1) out uint o_depth_bits;

void main() {
    o_slot = v_slot;
    o_depth_bits = v_depth_bits;
}
