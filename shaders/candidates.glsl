// The 32-bit raster's candidates (passes/raster_compute.py): the points whose depth
// pass lowered or met their pixel's depth. A pixel's final point is among them, since a
// point deeper than a depth its pixel already held can never be the least. Meta words
// (CandidateMeta: the candidates pass's dispatch arguments; from CANDIDATE_FALLBACK
// those of the index pass over each fill piece's points and the list's; CANDIDATE_HELD,
// 1 where every list held its candidates; from CANDIDATE_COUNTS each list's count, every
// point that was one, past its room too), then u_candidate_lists lists of
// u_list_capacity uvec4s each: pixel, depth bits, slot, and its reprojection list index
// (EMPTY for a slot of the store). A work group appends to the list its index picks, so
// that groups drawn at once (llvmpipe's threads) share neither a counter nor the cache
// lines their candidates fill. A shader defines CANDIDATES_ACCESS before the include.
layout(std430, binding = BINDING_CANDIDATES) CANDIDATES_ACCESS buffer Candidates {
    uint candidate_meta[CANDIDATE_META];
    uvec4 candidates[];
};
uniform uint u_candidate_lists;
uniform uint u_list_capacity;

// Whether every candidate of the frame found room (the arguments' program decided):
// else the index pass walks every point again, as without candidates.
bool candidates_held() {
    return candidate_meta[CANDIDATE_HELD] != 0u;
}
