// The shuffled point store (progressive/pointstore.py), and where each slot's record
// lives (StoreLayout). WORD_PLANES: four planes of one word a point, each in
// POINT_CHUNKS buffers of CHUNK_POINTS words (plane p's chunk c at binding
// POINTS_0 + p·POINT_CHUNKS + c): three position words relative to the point's batch
// (progressive/encoding.py), then the attribute word; load_point decodes them into a
// float record, so passes that need a whole point see the float layout. Else
// POINT_CHUNKS buffers of CHUNK_POINTS 16-byte records (xyz float bits relative to the
// origin, the attribute word).
#include "records.glsl"

#if WORD_PLANES
#if POINT_CHUNKS > 2
#error "the word store binds at most two buffers a plane"
#endif
// VECTOR_WORDS (a batch walk's four-word loads): the planes are read as uvec4s, a word
// as a component of one (every plane buffer holds a multiple of 4 words), and not written.
#ifdef VECTOR_WORDS
#define PLANE_ACCESS readonly
#define PLANE_TYPE uvec4
#define WORD_AT(a, index) a[(index) >> 2u][(index) & 3u]
#else
#define PLANE_ACCESS
#define PLANE_TYPE uint
#define WORD_AT(a, index) a[index]
#endif
layout(std430, binding = BINDING_POINTS_0) PLANE_ACCESS buffer Words0a { PLANE_TYPE words0a[]; };
layout(std430, binding = BINDING_POINTS_0 + POINT_CHUNKS) PLANE_ACCESS buffer Words1a { PLANE_TYPE words1a[]; };
layout(std430, binding = BINDING_POINTS_0 + 2 * POINT_CHUNKS) PLANE_ACCESS buffer Words2a { PLANE_TYPE words2a[]; };
layout(std430, binding = BINDING_POINTS_0 + 3 * POINT_CHUNKS) PLANE_ACCESS buffer Attributes0 { PLANE_TYPE attributes0[]; };
#if POINT_CHUNKS > 1
layout(std430, binding = BINDING_POINTS_1) PLANE_ACCESS buffer Words0b { PLANE_TYPE words0b[]; };
layout(std430, binding = BINDING_POINTS_1 + POINT_CHUNKS) PLANE_ACCESS buffer Words1b { PLANE_TYPE words1b[]; };
layout(std430, binding = BINDING_POINTS_1 + 2 * POINT_CHUNKS) PLANE_ACCESS buffer Words2b { PLANE_TYPE words2b[]; };
layout(std430, binding = BINDING_POINTS_1 + 3 * POINT_CHUNKS) PLANE_ACCESS buffer Attributes1 { PLANE_TYPE attributes1[]; };
#define PLANE_READ(a, b, index) ((index) < uint(CHUNK_POINTS) ? WORD_AT(a, index) : WORD_AT(b, (index) - uint(CHUNK_POINTS)))
#define QUAD_READ(a, b, index) ((index) < uint(CHUNK_POINTS) ? a[(index) >> 2u] : b[((index) - uint(CHUNK_POINTS)) >> 2u])
#define PLANE_WRITE(a, b, index, value) if ((index) < uint(CHUNK_POINTS)) a[index] = (value); else b[(index) - uint(CHUNK_POINTS)] = (value)
#else
#define PLANE_READ(a, b, index) WORD_AT(a, index)
#define QUAD_READ(a, b, index) a[(index) >> 2u]
#define PLANE_WRITE(a, b, index, value) a[index] = (value)
#endif

#ifdef VECTOR_WORDS
// Whether records first.. first + span - 1 can be read as quads: one buffer holds them
// all, and they start on a multiple of 4 in it.
bool quads_aligned(uint first, uint span) {
#if POINT_CHUNKS > 1
    if (first < uint(CHUNK_POINTS) && first + span > uint(CHUNK_POINTS)) return false;
    return ((first < uint(CHUNK_POINTS) ? first : first - uint(CHUNK_POINTS)) & 3u) == 0u;
#else
    return (first & 3u) == 0u;
#endif
}

// Plane `plane`'s words of records index.. index + 3 (index as quads_aligned allows).
uvec4 quad_words(uint plane, uint index) {
    if (plane == 0u) return QUAD_READ(words0a, words0b, index);
    if (plane == 1u) return QUAD_READ(words1a, words1b, index);
    if (plane == 2u) return QUAD_READ(words2a, words2b, index);
    return QUAD_READ(attributes0, attributes1, index);
}
#endif

layout(std430, binding = BINDING_BATCH_FRAMES) readonly buffer Frames { vec4 batch_frames[]; };  // base, step per batch

const uint LEVEL_MASK = 0x3FFu;
const uint HIDDEN_WORD = 0xFFFFFFFFu;
const uint CELLS = 1u << 30u;

uint point_word(uint index, uint level) {
    if (level == 0u) return PLANE_READ(words0a, words0b, index);
    if (level == 1u) return PLANE_READ(words1a, words1b, index);
    return PLANE_READ(words2a, words2b, index);
}

uint attribute_word(uint index) {
    return PLANE_READ(attributes0, attributes1, index);
}

// The cells of a point from its first `levels` words (1..3): the cell's centre below
// full precision, as progressive/encoding.py unpack_cells.
uvec3 point_cells(uvec3 words, uint levels) {
    uvec3 q = ((uvec3(words.x) >> uvec3(20u, 10u, 0u)) & LEVEL_MASK) << 20u;
    if (levels > 1u) q |= ((uvec3(words.y) >> uvec3(20u, 10u, 0u)) & LEVEL_MASK) << 10u;
    if (levels > 2u) q |= (uvec3(words.z) >> uvec3(20u, 10u, 0u)) & LEVEL_MASK;
    else q += uvec3(1u << (29u - 10u * levels));
    return q;
}

// A point's position relative to the origin as float bits (EMPTY for a point never
// drawn) from its first `levels` words, loaded already, in its batch's frame: base +
// float(q)·step, each operation rounded (progressive/encoding.py decode_frames, bit
// for bit).
uvec3 position_bits(uvec3 words, uint levels, vec3 base, vec3 step) {
    if (words.x == HIDDEN_WORD) return uvec3(EMPTY);
    // precise: no fused multiply-add, so every stage (and the numpy twin) rounds alike.
    precise vec3 offset = vec3(point_cells(words, levels)) * step;
    precise vec3 p = base + offset;
    return floatBitsToUint(p);
}

// The first `levels` words of record `index`, loaded together (none waits on another).
uvec3 point_words(uint index, uint levels) {
    return uvec3(point_word(index, 0u), levels > 1u ? point_word(index, 1u) : 0u, levels > 2u ? point_word(index, 2u) : 0u);
}

uvec3 decode_position(uint b, uint index, uint levels) {
    return position_bits(point_words(index, levels), levels, batch_frames[2u * b].xyz, batch_frames[2u * b + 1u].xyz);
}

uvec4 load_point(uint slot) {
    uint index = record_index(slot);
    return uvec4(decode_position(slot_batch_of(slot), index, 3u), attribute_word(index));
}

#ifndef VECTOR_WORDS
// Writes a slot's four words as distribute stages them (component < 0: the position
// words and the attribute word) or only its attribute word (component 3).
void store_point(uint slot, uvec4 words, int component) {
    uint index = record_index(slot);
    if (component < 0) {
        PLANE_WRITE(words0a, words0b, index, words.x);
        PLANE_WRITE(words1a, words1b, index, words.y);
        PLANE_WRITE(words2a, words2b, index, words.z);
    }
    PLANE_WRITE(attributes0, attributes1, index, words.w);
}
#endif
#else
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
#endif
