// The render contract (README): a point is drawn iff near <= depth <= far and it falls
// inside the image; ndc = scale * view xy (/ depth when perspective); pixel column
// floor((ndc.x*0.5+0.5)*W), row floor((0.5-ndc.y*0.5)*H),
// row 0 at the top. The view transform arrives camera-relative: u_view_rotation and
// u_view_translation = R*(origin - eye) are built in float64 on the CPU.

uniform mat3 u_view_rotation;
uniform vec3 u_view_translation;
uniform vec4 u_projection;   // x and y scales (f/aspect, f; orthographic 2/(height aspect), 2/height), near, far
uniform float u_perspective; // 1: divide by depth; 0: orthographic
uniform uvec2 u_size;        // width, height
uniform uint u_hidden[8];    // category codes not drawn, a bit each (classification toggles)
uniform vec3 u_clip_lo;      // the clip box relative to the origin (progressive/camera.py Clip),
uniform vec3 u_clip_hi;      // infinite sides where it has none
uniform vec4 u_section_line;  // a section (Clip.section): its start relative to the origin, unit XY axis;
uniform vec3 u_section_range; // along the axis from, to; half width across (none: -inf, inf, inf)

// Hidden categories are left out of the raster, so points behind them show. All bits
// are zero unless the shown attribute is a category (its code is the record's word).
bool category_shown(uint word) {
    uint c = min(word, 255u);
    return (u_hidden[c >> 5u] & (1u << (c & 31u))) == 0u;
}

// The section's rectangle in XY, in float32 exactly as progressive/camera.py
// section_keeps: `precise` forbids fusing the products, so both sides round alike.
bool section_keeps(vec3 p) {
    precise float qx = p.x - u_section_line.x;
    precise float qy = p.y - u_section_line.y;
    precise float t = qx * u_section_line.z + qy * u_section_line.w;
    precise float d = qy * u_section_line.z - qx * u_section_line.w;
    return t >= u_section_range.x && t <= u_section_range.y && abs(d) <= u_section_range.z;
}

// Points outside the clip box or its section are left out of the raster, like hidden categories.
bool clip_keeps(vec3 p) {
    return all(greaterThanEqual(p, u_clip_lo)) && all(lessThanEqual(p, u_clip_hi)) && section_keeps(p);
}

vec3 to_view(vec3 p) {
    return u_view_rotation * p + u_view_translation;
}

// A point already in view space into its pixel.
bool project_view(vec3 v, out uint pixel, out float depth) {
    depth = -v.z;
    if (!(depth >= u_projection.z && depth <= u_projection.w)) return false;
    float w = u_perspective != 0.0 ? depth : 1.0;
    float fx = (u_projection.x * v.x / w * 0.5 + 0.5) * float(u_size.x);
    float fy = (0.5 - u_projection.y * v.y / w * 0.5) * float(u_size.y);
    if (!(fx >= 0.0 && fx < float(u_size.x) && fy >= 0.0 && fy < float(u_size.y))) return false;
    pixel = uint(fy) * u_size.x + uint(fx);
    return true;
}

bool project(vec3 p, out uint pixel, out float depth) {
    return project_view(to_view(p), pixel, depth);
}
