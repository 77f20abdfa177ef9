// Scatter a staged batch into its permuted slots (paper section 3.3). With
// ATTRIBUTE_ONLY the stage holds one word per point (or RGB_BYTES, three bytes) and only
// word 3 is replaced (the word store's attribute plane, written batch by batch: attribute
// switching); with
// CLASS_WORDS each point's 16 flag bits (class, first and last return; CLASS_BYTES: made
// from its class and return bytes) go to the store's flags.
// The word store's points are encoded here, in their batch's frame (set before the
// scatter): from float records in float64, as progressive/encoding.py quantize and
// pack_words do, or (STAGED_CELLS) from a LAS file's own integers, staged as they are.
layout(local_size_x = 256) in;
#include "common.glsl"
#include "points.glsl"

#if CLASS_WORDS || ATTRIBUTE_ONLY || STAGED_CELLS
layout(std430, binding = BINDING_DISTRIBUTE) readonly buffer Stage { uint staged[]; };

// Byte j of the stage.
uint staged_byte(uint j) {
    return (staged[j >> 2u] >> ((j & 3u) << 3u)) & 0xFFu;
}
#endif

#if CLASS_WORDS
layout(std430, binding = BINDING_CLASSES) buffer Classes { uint classes[]; };
#elif ATTRIBUTE_ONLY || STAGED_CELLS
// Point i's attribute word, the words starting at word `first` of the stage. RGB_BYTES:
// the stage holds each point's R, G, B bytes back to back (3 a point: a quarter less to
// write to the staging memory than words, and nothing packed on the CPU), made the word
// R | G << 8 | B << 16 | 0xFF000000 here, as loaders/records.py attribute_word makes it.
uint staged_word(uint first, uint i) {
#if RGB_BYTES
    uint j = 4u * first + 3u * i;
    return staged_byte(j) | (staged_byte(j + 1u) << 8u) | (staged_byte(j + 2u) << 16u) | 0xFF000000u;
#else
    return staged[first + i];
#endif
}
#else
layout(std430, binding = BINDING_DISTRIBUTE) readonly buffer Stage { uvec4 staged[]; };
#endif

uniform uint u_start;       // file-order index of staged[0]
uniform uint u_count;
uniform uint u_prime;
uniform uint u_rotation;
uniform uint u_batches;    // batched layout (0: one shuffle)
uniform uint u_capacity;    // slots held on the GPU: the rest of the cloud is left out

#if CLASS_WORDS
// Point i's 16 flag bits (shaders/classes.glsl): staged as made (progressive/scene.py
// point_flags), or with CLASS_BYTES made here from the piece's classes, then return
// numbers, then numbers of returns, a byte each (three copies on the CPU): the class,
// bit 8 where the number is at most 1 (first), bit 9 where it is at least the count (last).
uint staged_flags(uint i) {
#if CLASS_BYTES
    uint number = staged_byte(u_count + i), count = staged_byte(2u * u_count + i);
    return staged_byte(i) | (number <= 1u ? 0x100u : 0u) | (number >= count ? 0x200u : 0u);
#else
    return staged[i] & 0xFFFFu;
#endif
}
#endif

#if WORD_PLANES && !ATTRIBUTE_ONLY && !CLASS_WORDS
// Cells in [0, 2^30) as three words of 10+10+10 bits (progressive/encoding.py
// pack_words); EMPTY cells mark a point never drawn: HIDDEN_WORD in every word.
uvec4 pack_cells(uvec3 q, uint word) {
    if (q.x == EMPTY) return uvec4(HIDDEN_WORD, HIDDEN_WORD, HIDDEN_WORD, word);
    uvec3 words;
    for (uint level = 0u; level < 3u; ++level) {
        uvec3 part = (q >> (10u * (2u - level))) & LEVEL_MASK;
        words[level] = (part.x << 20u) | (part.y << 10u) | part.z;
    }
    return uvec4(words, word);
}

#if STAGED_CELLS
// A LAS point staged as the file's integers: the piece's X, Y, Z of every point, then
// their attribute words, or with RGB_BYTES their R, G, B bytes (copies on the CPU). Its
// cells are its integers less its batch's least ones, moved up the batch's shifts (the
// cell frame, encoding.py cell_frames: lossless, under 2^30); EMPTY where
// u_hide_nonfinite and the word is a scalar that is not finite (a point never drawn, as
// packing.py hides it).
layout(std430, binding = BINDING_BATCH_CELLS) readonly buffer CellFrames { uvec4 cell_frames[]; };
uniform uint u_hide_nonfinite;

uvec4 encode_words(uint index, uint i) {
    uint word = staged_word(3u * u_count, i);
    if (u_hide_nonfinite != 0u && (word & 0x7F800000u) == 0x7F800000u) return pack_cells(uvec3(EMPTY), word);
    uvec4 frame = cell_frames[index / BATCH_POINTS];
    uvec3 shift = (uvec3(frame.w) >> uvec3(0u, 8u, 16u)) & 0xFFu;
    uvec3 integers = uvec3(staged[3u * i], staged[3u * i + 1u], staged[3u * i + 2u]);
    return pack_cells((integers - frame.xyz) << shift, word);
}
#else
// A float record (xyz float bits relative to the origin, the attribute word) in its
// batch's frame: cells round((p - base) / step), nearest even, in [0, 2^30), in float64
// as encoding.py quantize.
uvec4 encode_words(uint index, uvec4 record) {
    if (!finite_position(record)) return pack_cells(uvec3(EMPTY), record.w);
    uint b = index / BATCH_POINTS;
    dvec3 cells = (dvec3(uintBitsToFloat(record.xyz)) - dvec3(batch_frames[2u * b].xyz)) / dvec3(batch_frames[2u * b + 1u].xyz);
    return pack_cells(uvec3(clamp(roundEven(cells), dvec3(0.0), dvec3(double(CELLS - 1u)))), record.w);
}
#endif
#endif

void main() {
    uint i;
    if (!range_index(u_count, i)) return;
#if ATTRIBUTE_ONLY && WORD_PLANES
    // The word store is batched: a slot's record is its batch's first record plus its
    // shuffled index (records batch after batch; StoreLayout), found without a division.
    uint index = u_start + i;
    uint b = index / BATCH_POINTS;
    uint shuffled = batch_shuffle(index - b * BATCH_POINTS, b, u_rotation);
    uint piece = shuffled / SLICE_POINTS;
    uint slot = piece * (u_batches * SLICE_POINTS) + b * SLICE_POINTS + (shuffled - piece * SLICE_POINTS);
    if (slot >= u_capacity) return;
    uint record = store_batches == 0u ? slot : batch_record(b) + shuffled;
    set_plane_word(3u, record, staged_word(0u, i));
#else
    uint slot = slot_of(u_start + i, u_prime, u_rotation, u_batches);
    if (slot >= u_capacity) return;
#if CLASS_WORDS
    // Each slot is written once (the buffer starts at zero), two slots share a word.
    atomicOr(classes[slot >> 1u], staged_flags(i) << ((slot & 1u) * 16u));
#elif ATTRIBUTE_ONLY
    store_point(slot, uvec4(0u, 0u, 0u, staged_word(0u, i)), 3);
#elif STAGED_CELLS
    store_point(slot, encode_words(u_start + i, i), -1);
#elif WORD_PLANES
    store_point(slot, encode_words(u_start + i, staged[i]), -1);
#else
    store_point(slot, staged[i], -1);
#endif
#endif
}
