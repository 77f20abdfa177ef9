// Where each slot's record lives (progressive/pointstore.py StoreLayout, the twin).
// store_batches == 0: record i holds slot i. Else the batched layout's slots (slice k
// of every batch before slice k+1 of any) are stored batch after batch, so a batch's
// records are contiguous: batch b holds store_slices slices, one more if b <
// store_longer, and batch store_longer also the first store_rest slots of its next
// slice (a store that keeps part of the cloud keeps exactly its capacity).
// point_batches: the permutation's batches, whatever the record order (the batch of a
// slot, slot_batch_of, for the word store's decoding).
layout(std140, binding = UNIFORM_STORE_LAYOUT) uniform StoreLayout {
    uint store_batches, store_slices, store_longer, store_rest;
    uint point_batches;
};

uint slot_batch_of(uint slot) {
    return (slot % (point_batches * SLICE_POINTS)) / SLICE_POINTS;
}

uint batch_record(uint b) {
    return (b * store_slices + min(b, store_longer)) * SLICE_POINTS + (b > store_longer ? store_rest : 0u);
}

uint record_index(uint slot) {
    if (store_batches == 0u) return slot;
    uint round = store_batches * SLICE_POINTS;
    uint k = slot / round;
    uint within = slot - k * round;
    uint b = within / SLICE_POINTS;
    return batch_record(b) + k * SLICE_POINTS + (within - b * SLICE_POINTS);
}
