// Eye-dome lighting (Boucheny 2009; webgpu-point-rendering-engine section 6.3):
// darken each covered pixel by how much farther it is than its 8 neighbours at
// `radius` pixels, in log2 depth, so shape reads without normals. In place on the
// resolved image; only depth is read from the visibility buffer.
layout(local_size_x = 16, local_size_y = 16) in;
#include "common.glsl"

#define VISIBILITY_ACCESS readonly
#include "visibility.glsl"
layout(std430, binding = BINDING_IMAGE) buffer Image { uint image[]; };

uniform uvec2 u_size;
uniform float u_strength;
uniform float u_radius;

const vec2 DIRECTIONS[8] = vec2[8](vec2(1, 0), vec2(-1, 0), vec2(0, 1), vec2(0, -1),
                                   vec2(0.70710678, 0.70710678), vec2(-0.70710678, 0.70710678),
                                   vec2(0.70710678, -0.70710678), vec2(-0.70710678, -0.70710678));

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    ivec2 size = ivec2(u_size);
    if (p.x >= size.x || p.y >= size.y) return;
    uint pixel = uint(p.y * size.x + p.x);
    if (visibility[2u * pixel] == EMPTY) return;
    float here = log2(uintBitsToFloat(visibility[2u * pixel + 1u]));
    float sum = 0.0;
    for (int k = 0; k < 8; ++k) {
        ivec2 q = p + ivec2(round(DIRECTIONS[k] * u_radius));
        if (any(lessThan(q, ivec2(0))) || any(greaterThanEqual(q, size))) continue;
        uint qi = uint(q.y * size.x + q.x);
        if (visibility[2u * qi] == EMPTY) continue;
        sum += max(0.0, here - log2(uintBitsToFloat(visibility[2u * qi + 1u])));
    }
    float shade = exp(-300.0 * u_strength * sum / 8.0);
    vec4 c = unpackUnorm4x8(image[pixel]);
    image[pixel] = packUnorm4x8(vec4(c.rgb * shade, c.a));
}
