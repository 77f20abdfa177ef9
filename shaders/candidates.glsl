// The 32-bit raster's candidates (passes/raster_compute.py): the points whose depth
// pass lowered or met their pixel's depth. A pixel's final point is among them, since a
// point deeper than a depth its pixel already held can never be the least. Meta words
// (CANDIDATE_COUNT: every point that was one, past the capacity too; the candidates
// pass's dispatch arguments; from CANDIDATE_FALLBACK those of the index pass over each
// fill piece's points and the list's), then a uvec4 each: pixel, depth bits, slot,
// and its reprojection list index (EMPTY for a slot of the store). A shader defines
// CANDIDATES_ACCESS before the include.
layout(std430, binding = BINDING_CANDIDATES) CANDIDATES_ACCESS buffer Candidates {
    uint candidate_meta[CANDIDATE_META];
    uvec4 candidates[];
};
uniform uint u_candidate_capacity;

// Whether every candidate of the frame found room: else the index pass walks every
// point again, as without candidates.
bool candidates_held() {
    return candidate_meta[CANDIDATE_COUNT] <= u_candidate_capacity;
}
