// Colour the visibility buffer: only visible points are read (a visibility buffer).
layout(local_size_x = 16, local_size_y = 16) in;
#include "common.glsl"
#include "points.glsl"

#define VISIBILITY_ACCESS readonly
#include "visibility.glsl"
layout(std430, binding = BINDING_IMAGE) writeonly buffer Image { uint image[]; };
layout(std430, binding = BINDING_PALETTE) readonly buffer Palette { uint palette[256]; };
#if PIXEL_WORDS
// Progressive frames: prepare already copied each visible point's word (no gathers).
layout(std430, binding = BINDING_PIXEL_WORDS) readonly buffer PixelWords { uint pixel_words[]; };
uint visible_word(uint pixel, uint slot) { return pixel_words[pixel]; }
#else
uint visible_word(uint pixel, uint slot) { return load_point(slot).w; }
#endif

uniform uvec2 u_size;
uniform int u_mode;          // COLOR_MODE_* (progressive/colors.py ColorMode)
uniform vec2 u_range;        // scalar: value at palette[0] and palette[255]
uniform uint u_background;   // RGBA8

uint shade(uint word) {
    if (u_mode == COLOR_MODE_RGB) return word | 0xFF000000u;
    if (u_mode == COLOR_MODE_CATEGORY) return palette[min(word, 255u)];
    float value = uintBitsToFloat(word);
    if (isnan(value)) return u_background;
    float span = u_range.y - u_range.x;
    float t = span > 0.0 ? clamp((value - u_range.x) / span, 0.0, 1.0) : 0.5;
    return palette[uint(t * 255.0 + 0.5)];
}

void main() {
    uvec2 p = gl_GlobalInvocationID.xy;
    if (p.x >= u_size.x || p.y >= u_size.y) return;
    uint pixel = p.y * u_size.x + p.x;
    uint slot = visibility[2u * pixel];
    image[pixel] = slot == EMPTY ? u_background : shade(visible_word(pixel, slot));
}
