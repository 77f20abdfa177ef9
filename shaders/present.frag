// The resolved image (RGBA8 words, row 0 at the top) onto the window (row 0 at the bottom).
layout(std430, binding = BINDING_IMAGE) readonly buffer Image { uint image[]; };
uniform uvec2 u_size;
out vec4 color;

void main() {
    uvec2 p = uvec2(gl_FragCoord.xy);
    if (p.x >= u_size.x || p.y >= u_size.y) {
        color = vec4(0.0, 0.0, 0.0, 1.0);
        return;
    }
    color = unpackUnorm4x8(image[(u_size.y - 1u - p.y) * u_size.x + p.x]);
}
