// The visibility buffer (progressive/passes/visibility.py): per pixel the slot of its
// nearest point, then that point's depth bits; as a little-endian uint64 the key the
// 64-bit atomicMin sorts by. A shader defines VISIBILITY_ACCESS before the include
// (readonly, writeonly, or empty to read and write), and VISIBILITY_64 to see each
// pixel as one uint64_t.
#ifndef VISIBILITY_ACCESS
#error "define VISIBILITY_ACCESS before including visibility.glsl"
#endif
#ifdef VISIBILITY_64
layout(std430, binding = BINDING_VISIBILITY) VISIBILITY_ACCESS buffer Visibility { uint64_t visibility[]; };
#else
layout(std430, binding = BINDING_VISIBILITY) VISIBILITY_ACCESS buffer Visibility { uint visibility[]; };
#endif
