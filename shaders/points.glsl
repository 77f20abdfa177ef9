// The shuffled point buffer: POINT_CHUNKS storage blocks of CHUNK_POINTS 16-byte
// records each (xyz float bits relative to the origin, one attribute word), and
// where each slot's record lives (progressive/pointstore.py StoreLayout).

layout(std430, binding = BINDING_POINTS_0) buffer Points0 { uvec4 points0[]; };
#if POINT_CHUNKS > 1
layout(std430, binding = BINDING_POINTS_1) buffer Points1 { uvec4 points1[]; };
#endif
#if POINT_CHUNKS > 2
layout(std430, binding = BINDING_POINTS_2) buffer Points2 { uvec4 points2[]; };
#endif
#if POINT_CHUNKS > 3
layout(std430, binding = BINDING_POINTS_3) buffer Points3 { uvec4 points3[]; };
#endif
#if POINT_CHUNKS > 4
layout(std430, binding = BINDING_POINTS_4) buffer Points4 { uvec4 points4[]; };
#endif
#if POINT_CHUNKS > 5
layout(std430, binding = BINDING_POINTS_5) buffer Points5 { uvec4 points5[]; };
#endif
#if POINT_CHUNKS > 6
layout(std430, binding = BINDING_POINTS_6) buffer Points6 { uvec4 points6[]; };
#endif
#if POINT_CHUNKS > 7
layout(std430, binding = BINDING_POINTS_7) buffer Points7 { uvec4 points7[]; };
#endif

#include "records.glsl"

uvec4 load_record(uint index) {
    uint c = index / uint(CHUNK_POINTS);
    uint j = index - c * uint(CHUNK_POINTS);
    switch (c) {
    case 0u: return points0[j];
#if POINT_CHUNKS > 1
    case 1u: return points1[j];
#endif
#if POINT_CHUNKS > 2
    case 2u: return points2[j];
#endif
#if POINT_CHUNKS > 3
    case 3u: return points3[j];
#endif
#if POINT_CHUNKS > 4
    case 4u: return points4[j];
#endif
#if POINT_CHUNKS > 5
    case 5u: return points5[j];
#endif
#if POINT_CHUNKS > 6
    case 6u: return points6[j];
#endif
#if POINT_CHUNKS > 7
    case 7u: return points7[j];
#endif
    }
    return uvec4(EMPTY);
}

uvec4 load_point(uint slot) {
    return load_record(record_index(slot));
}

// Writes the whole record (component < 0) or one word of it.
void store_point(uint slot, uvec4 record, int component) {
    uint index = record_index(slot);
    uint c = index / uint(CHUNK_POINTS);
    uint j = index - c * uint(CHUNK_POINTS);
#define STORE(buf) if (component < 0) buf[j] = record; else buf[j][component] = record[component]
    switch (c) {
    case 0u: STORE(points0); break;
#if POINT_CHUNKS > 1
    case 1u: STORE(points1); break;
#endif
#if POINT_CHUNKS > 2
    case 2u: STORE(points2); break;
#endif
#if POINT_CHUNKS > 3
    case 3u: STORE(points3); break;
#endif
#if POINT_CHUNKS > 4
    case 4u: STORE(points4); break;
#endif
#if POINT_CHUNKS > 5
    case 5u: STORE(points5); break;
#endif
#if POINT_CHUNKS > 6
    case 6u: STORE(points6); break;
#endif
#if POINT_CHUNKS > 7
    case 7u: STORE(points7); break;
#endif
    }
#undef STORE
}
