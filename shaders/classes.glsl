// The class each slot's point has, where the store keeps them (CLASS_FILTER: hidden
// classes apply whatever attribute is shown); else the shown word is the class.

#if CLASS_FILTER
layout(std430, binding = BINDING_CLASSES) readonly buffer Classes { uint classes[]; };  // four slots a word
uint point_class(uint slot, uint word) {
    return (classes[slot >> 2u] >> ((slot & 3u) * 8u)) & 0xFFu;
}
#else
uint point_class(uint slot, uint word) {
    return word;
}
#endif
