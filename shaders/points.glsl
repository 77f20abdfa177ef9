// The shuffled point store (progressive/pointstore.py), and where each slot's record
// lives (StoreLayout). WORD_PLANES: four words a point, three position words relative
// to the point's batch (progressive/encoding.py), then the attribute word, in blocks of
// BLOCK_RECORDS records holding each word plane in turn (record r's plane p at word
// (block·4 + p)·BLOCK_RECORDS + r mod BLOCK_RECORDS), POINT_CHUNKS buffers of
// CHUNK_POINTS records (a multiple of BLOCK_RECORDS) at bindings POINTS_0..: a point's
// four words, and a slice's, lie within one block (64 KiB), where a gather or a thin
// fill piece finds them with one address translation, not one a plane. load_point
// decodes them into a float record, so passes that need a whole point see the float
// layout. Else POINT_CHUNKS buffers of CHUNK_POINTS 16-byte records (xyz float bits
// relative to the origin, the attribute word).
#include "records.glsl"

#if WORD_PLANES
// VECTOR_WORDS (a batch walk's four-word loads): the blocks are read as uvec4s, a word
// as a component of one (BLOCK_RECORDS is a multiple of 4), and not written.
#ifdef VECTOR_WORDS
#define STORE_ACCESS readonly
#define STORE_TYPE uvec4
#define WORD_AT(a, w) a[(w) >> 2u][(w) & 3u]
#else
#define STORE_ACCESS
#define STORE_TYPE uint
#define WORD_AT(a, w) a[w]
#endif
#else
#define STORE_ACCESS
#define STORE_TYPE uvec4
#endif
// The store's buffers, and for each beyond the first its case of SWITCH_CHUNK (bound by
// index, so a buffer is chosen by a switch).
layout(std430, binding = BINDING_POINTS_0) STORE_ACCESS buffer Store0 { STORE_TYPE store0[]; };
#if POINT_CHUNKS > 1
layout(std430, binding = BINDING_POINTS_1) STORE_ACCESS buffer Store1 { STORE_TYPE store1[]; };
#define CHUNK_CASE_1(S) case 1u: S(store1); break;
#else
#define CHUNK_CASE_1(S)
#endif
#if POINT_CHUNKS > 2
layout(std430, binding = BINDING_POINTS_2) STORE_ACCESS buffer Store2 { STORE_TYPE store2[]; };
#define CHUNK_CASE_2(S) case 2u: S(store2); break;
#else
#define CHUNK_CASE_2(S)
#endif
#if POINT_CHUNKS > 3
layout(std430, binding = BINDING_POINTS_3) STORE_ACCESS buffer Store3 { STORE_TYPE store3[]; };
#define CHUNK_CASE_3(S) case 3u: S(store3); break;
#else
#define CHUNK_CASE_3(S)
#endif
#if POINT_CHUNKS > 4
layout(std430, binding = BINDING_POINTS_4) STORE_ACCESS buffer Store4 { STORE_TYPE store4[]; };
#define CHUNK_CASE_4(S) case 4u: S(store4); break;
#else
#define CHUNK_CASE_4(S)
#endif
#if POINT_CHUNKS > 5
layout(std430, binding = BINDING_POINTS_5) STORE_ACCESS buffer Store5 { STORE_TYPE store5[]; };
#define CHUNK_CASE_5(S) case 5u: S(store5); break;
#else
#define CHUNK_CASE_5(S)
#endif
#if POINT_CHUNKS > 6
layout(std430, binding = BINDING_POINTS_6) STORE_ACCESS buffer Store6 { STORE_TYPE store6[]; };
#define CHUNK_CASE_6(S) case 6u: S(store6); break;
#else
#define CHUNK_CASE_6(S)
#endif
#if POINT_CHUNKS > 7
layout(std430, binding = BINDING_POINTS_7) STORE_ACCESS buffer Store7 { STORE_TYPE store7[]; };
#define CHUNK_CASE_7(S) case 7u: S(store7); break;
#else
#define CHUNK_CASE_7(S)
#endif

// STATEMENT(a) on buffer c's array a.
#define SWITCH_CHUNK(c, STATEMENT) switch (c) { case 0u: STATEMENT(store0); break; \
    CHUNK_CASE_1(STATEMENT) CHUNK_CASE_2(STATEMENT) CHUNK_CASE_3(STATEMENT) CHUNK_CASE_4(STATEMENT) \
    CHUNK_CASE_5(STATEMENT) CHUNK_CASE_6(STATEMENT) CHUNK_CASE_7(STATEMENT) }

#if WORD_PLANES
const uint BLOCKS_A_CHUNK = uint(CHUNK_POINTS) / uint(BLOCK_RECORDS);

// The buffer of record `index` and the word of its plane `plane` in it.
uvec2 word_place(uint plane, uint index) {
    uint block = index / uint(BLOCK_RECORDS);
    uint c = block / BLOCKS_A_CHUNK;
    return uvec2(c, ((block - c * BLOCKS_A_CHUNK) * 4u + plane) * uint(BLOCK_RECORDS) + (index - block * uint(BLOCK_RECORDS)));
}

// Word w of buffer c (a place from word_place; plane p + k of a record is k·BLOCK_RECORDS on).
uint word_in(uint c, uint w) {
    uint v = EMPTY;
#define READ_WORD(a) v = WORD_AT(a, w)
    SWITCH_CHUNK(c, READ_WORD)
#undef READ_WORD
    return v;
}

uint plane_word(uint plane, uint index) {
    uvec2 at = word_place(plane, index);
    return word_in(at.x, at.y);
}

#ifdef VECTOR_WORDS
// Whether records first.. can be read as quads: they start on a multiple of 4 (a quad
// never leaves its block, nor so its buffer).
bool quads_aligned(uint first, uint span) {
    return (first & 3u) == 0u;
}

// Plane `plane`'s words of records index.. index + 3 (index as quads_aligned allows).
uvec4 quad_words(uint plane, uint index) {
    uvec2 at = word_place(plane, index);
    uvec4 q = uvec4(EMPTY);
#define READ_QUAD(a) q = a[at.y >> 2u]
    SWITCH_CHUNK(at.x, READ_QUAD)
#undef READ_QUAD
    return q;
}
#else
void set_plane_word(uint plane, uint index, uint value) {
    uvec2 at = word_place(plane, index);
#define WRITE_WORD(a) a[at.y] = value
    SWITCH_CHUNK(at.x, WRITE_WORD)
#undef WRITE_WORD
}
#endif

layout(std430, binding = BINDING_BATCH_FRAMES) readonly buffer Frames { vec4 batch_frames[]; };  // base, step per batch

const uint LEVEL_MASK = 0x3FFu;
const uint HIDDEN_WORD = 0xFFFFFFFFu;
const uint CELLS = 1u << 30u;

uint attribute_word(uint index) {
    return plane_word(3u, index);
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
    uvec2 at = word_place(0u, index);
    return uvec3(word_in(at.x, at.y), levels > 1u ? word_in(at.x, at.y + uint(BLOCK_RECORDS)) : 0u,
                 levels > 2u ? word_in(at.x, at.y + 2u * uint(BLOCK_RECORDS)) : 0u);
}

uvec3 decode_position(uint b, uint index, uint levels) {
    return position_bits(point_words(index, levels), levels, batch_frames[2u * b].xyz, batch_frames[2u * b + 1u].xyz);
}

uvec4 load_point(uint slot) {
    uint index = record_index(slot);
    uvec2 at = word_place(0u, index);
    uvec3 words = uvec3(word_in(at.x, at.y), word_in(at.x, at.y + uint(BLOCK_RECORDS)),
                        word_in(at.x, at.y + 2u * uint(BLOCK_RECORDS)));
    uint b = slot_batch_of(slot);
    return uvec4(position_bits(words, 3u, batch_frames[2u * b].xyz, batch_frames[2u * b + 1u].xyz),
                 word_in(at.x, at.y + 3u * uint(BLOCK_RECORDS)));
}

#ifndef VECTOR_WORDS
// Writes a slot's four words as distribute stages them (component < 0: the position
// words and the attribute word) or only its attribute word (component 3).
void store_point(uint slot, uvec4 words, int component) {
    uint index = record_index(slot);
    if (component < 0) {
        set_plane_word(0u, index, words.x);
        set_plane_word(1u, index, words.y);
        set_plane_word(2u, index, words.z);
    }
    set_plane_word(3u, index, words.w);
}
#endif
#else
uvec4 load_record(uint index) {
    uint c = index / uint(CHUNK_POINTS);
    uint j = index - c * uint(CHUNK_POINTS);
    uvec4 r = uvec4(EMPTY);
#define READ_RECORD(a) r = a[j]
    SWITCH_CHUNK(c, READ_RECORD)
#undef READ_RECORD
    return r;
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
    SWITCH_CHUNK(c, STORE)
#undef STORE
}
#endif
