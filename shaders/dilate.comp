// Point size above one pixel as a screen-space pass: every output pixel takes the
// nearest (least depth, then least slot) visible point whose disc of `point size`
// pixels covers it. Rasterization and reprojection stay one pixel per point, so
// convergence stays exact; only what resolve colours changes.
layout(local_size_x = 16, local_size_y = 16) in;
#include "common.glsl"

#define VISIBILITY_ACCESS readonly
#include "visibility.glsl"
layout(std430, binding = BINDING_DILATED) writeonly buffer Dilated { uint dilated[]; };
#if PIXEL_WORDS
layout(std430, binding = BINDING_PIXEL_WORDS) readonly buffer PixelWords { uint pixel_words[]; };
layout(std430, binding = BINDING_DILATED_WORDS) writeonly buffer DilatedWords { uint dilated_words[]; };
#endif

uniform uvec2 u_size;
uniform int u_reach;        // largest |dx| or |dy| of the footprint
uniform float u_radius2;    // footprint: dx*dx + dy*dy <= u_radius2

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = ivec2(u_size);
    if (p.x >= size.x || p.y >= size.y) return;
    uint best_slot = EMPTY;
    uint best_depth = EMPTY;
    uint best_pixel = 0u;
    // Row by row: the disc's half-width in row dy (exactly the test dx² + dy² <=
    // u_radius2 in float), cut to the image, so no tap is tested and skipped.
    for (int dy = max(-u_reach, -p.y); dy <= min(u_reach, size.y - 1 - p.y); ++dy) {
        int w = int(sqrt(max(u_radius2 - float(dy * dy), 0.0)));
        while (float((w + 1) * (w + 1) + dy * dy) <= u_radius2) ++w;
        while (w >= 0 && float(w * w + dy * dy) > u_radius2) --w;
        uint row = uint((p.y + dy) * size.x);
        for (int qx = max(p.x - w, 0); qx <= min(p.x + w, size.x - 1); ++qx) {
            uint qi = row + uint(qx);
            uint slot = visibility[2u * qi];
            uint depth = visibility[2u * qi + 1u];
            if (slot != EMPTY && (depth < best_depth || (depth == best_depth && slot < best_slot))) {
                best_slot = slot;
                best_depth = depth;
                best_pixel = qi;
            }
        }
    }
    uint pixel = uint(p.y * size.x + p.x);
    dilated[2u * pixel] = best_slot;
    dilated[2u * pixel + 1u] = best_depth;
#if PIXEL_WORDS
    if (best_slot != EMPTY) dilated_words[pixel] = pixel_words[best_pixel];
#endif
}
