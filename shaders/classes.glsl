// Each slot's point flags, where the store keeps them (CLASS_FILTER: hidden classes and
// return filters apply whatever attribute is shown): 16 bits a slot, the class in the
// low byte, bit 8 first return, bit 9 last return (progressive/scene.py point_flags).
// Without them the shown word is the class and every return is drawn.

uniform uint u_returns;      // progressive/camera.py Returns: 0 all, 1 first, 2 last, 3 single

#if CLASS_FILTER
layout(std430, binding = BINDING_CLASSES) readonly buffer Classes { uint classes[]; };  // two slots a word
uint point_flags(uint slot, uint word) {
    return (classes[slot >> 1u] >> ((slot & 1u) * 16u)) & 0xFFFFu;
}
#else
uint point_flags(uint slot, uint word) {
    return min(word, 255u) | 0x300u;
}
#endif

bool returns_shown(uint flags) {
    bool first = (flags & 0x100u) != 0u, last = (flags & 0x200u) != 0u;
    return u_returns == 0u || (u_returns == 1u && first) || (u_returns == 2u && last) || (u_returns == 3u && first && last);
}

bool flags_shown(uint flags) {
    return category_shown(flags & 0xFFu) && returns_shown(flags);
}
