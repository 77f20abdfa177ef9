// Batches with a point that improved a pixel this frame (the raster's deciding pass,
// or the index pass over its candidates): the winners pass walks only those, so a batch
// that no longer changes the image costs it one read. u_mark: 0 for brute force, which
// has no winners pass. Read before written, as the atomics are: the points of a batch's
// work group mostly find their batch marked already.
layout(std430, binding = BINDING_IMPROVED) buffer Improved { uint improved[]; };
uniform uint u_mark;

void mark_improved(uint slot) {
    uint b = slot_batch_of(slot);
    if (u_mark != 0u && improved[b] == 0u) improved[b] = 1u;
}
