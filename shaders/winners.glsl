// The winners pass's per-pixel records (passes/handles.py Winners): pixel p's record
// at uvec4 p, its slot at word p after the records (u_winner_pixels of them). A shader
// defines WINNERS_ACCESS before the include.
#ifndef WINNERS_ACCESS
#error "define WINNERS_ACCESS before including winners.glsl"
#endif
layout(std430, binding = BINDING_WINNERS) WINNERS_ACCESS buffer Winners { uvec4 winners[]; };
uniform uint u_winner_pixels;
#define WINNER_SLOT(pixel) winners[u_winner_pixels + ((pixel) >> 2u)][(pixel) & 3u]
