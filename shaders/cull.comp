// Per batch, whether its box can hold a point in view (progressive/batches.py in_view)
// and how many of its position words the raster reads (progressive/encoding.py
// levels_needed): one invocation a batch, once a frame; the rasterizer skips points of
// batches flagged 0 and reads the flag's number of words of the others.
layout(local_size_x = 256) in;
#include "common.glsl"
#include "camera.glsl"

layout(std430, binding = BINDING_BATCH_BOXES) readonly buffer Boxes { vec4 boxes[]; };  // min, max per batch
layout(std430, binding = BINDING_BATCH_FLAGS) writeonly buffer Flags { uint batch_flags[]; };
uniform uint u_batches;
#if ADAPTIVE
layout(std430, binding = BINDING_BATCH_FRAMES) readonly buffer Frames { vec4 batch_frames[]; };  // base, step per batch
uniform float u_error_px;    // the adaptive precision's bound (encoding.py ADAPTIVE_ERROR_PX)
uniform float u_pixel_scale; // pixels a unit of displacement may move a point at depth 1 (encoding.py pixel_scale)
#endif

// Whether the box's XY rectangle can meet the section's (progressive/batches.py
// section_meets): their projections on the section's axis and on its normal overlap,
// with BOX_MARGIN of slack. Without a section the ranges are infinite: always true.
bool section_meets(vec3 lo, vec3 hi) {
    vec2 u = u_section_line.zw;
    vec2 c = 0.5 * (lo.xy + hi.xy) - u_section_line.xy, e = 0.5 * (hi.xy - lo.xy);
    float t = dot(c, u), rt = dot(e, abs(u));
    float d = c.y * u.x - c.x * u.y, rd = dot(e, abs(vec2(u.y, u.x)));
    float t_from = u_section_range.x, t_to = u_section_range.y, half_width = u_section_range.z;
    vec2 m = max(abs(lo.xy), abs(hi.xy)) + abs(u_section_line.xy);   // the magnitudes c was rounded at
    float st = BOX_MARGIN * (abs(t) + rt + abs(t_from) + abs(t_to) + m.x + m.y) + 1e-30;
    float sd = BOX_MARGIN * (abs(d) + rd + half_width + m.x + m.y) + 1e-30;
    return t + rt >= t_from - st && t - rt <= t_to + st && abs(d) - rd <= half_width + sd;
}

// The frustum test of progressive/batches.py in_view: false iff the box is empty or
// some plane has all eight corners (padded by BOX_MARGIN) outside it by more than
// BOX_MARGIN of the terms it compares. Never false for a box holding a drawn point.
bool batch_in_view(uint b, out float depth_min) {
    depth_min = 0.0;
    vec3 lo = boxes[2u * b].xyz, hi = boxes[2u * b + 1u].xyz;
    if (!all(lessThanEqual(lo, hi))) return false;
    // The box and the clip box compare in the same float32 frame as clip_keeps: exact.
    if (!all(lessThanEqual(lo, u_clip_hi)) || !all(greaterThanEqual(hi, u_clip_lo))) return false;
    if (!section_meets(lo, hi)) return false;
    vec3 pad = BOX_MARGIN * ((hi - lo) + max(abs(lo), abs(hi))) + 1e-30;
    lo -= pad;
    hi += pad;
    float near = u_projection.z, far = u_projection.w;
    bool out_near = true, out_far = true, out_right = true, out_left = true, out_top = true, out_bottom = true;
    depth_min = uintBitsToFloat(0x7F800000u);   // +infinity
    for (int c = 0; c < 8; ++c) {
        vec3 v = to_view(vec3((c & 1) != 0 ? hi.x : lo.x, (c & 2) != 0 ? hi.y : lo.y, (c & 4) != 0 ? hi.z : lo.z));
        float depth = -v.z, d = abs(depth);
        depth_min = min(depth_min, depth);
        float w = u_perspective != 0.0 ? depth : 1.0, aw = abs(w);    // the side planes: |x| <= w
        float x = u_projection.x * v.x, y = u_projection.y * v.y;
        float tx = BOX_MARGIN * (aw + abs(x)), ty = BOX_MARGIN * (aw + abs(y));
        out_near = out_near && depth - near + BOX_MARGIN * (d + near) < 0.0;
        out_far = out_far && far - depth + BOX_MARGIN * (d + far) < 0.0;
        out_right = out_right && w - x + tx < 0.0;
        out_left = out_left && w + x + tx < 0.0;
        out_top = out_top && w - y + ty < 0.0;
        out_bottom = out_bottom && w + y + ty < 0.0;
    }
    return !(out_near || out_far || out_right || out_left || out_top || out_bottom);
}

#if ADAPTIVE
// The fewest words whose error, projected, stays under u_error_px for every point of
// the batch: a cell's half diagonal e moves a point at depth z by at most
// e·u_pixel_scale/z pixels, and a drawn point's exact depth is at least the box's
// least corner depth and near - e (progressive/encoding.py levels_needed, the twin).
uint batch_levels(uint b, float depth_min) {
    vec3 step = batch_frames[2u * b + 1u].xyz;
    // float32 decoding rounds float(q), the product and the sum, each at most the
    // magnitude of the base and the batch's extent
    float rounding = FLOAT_ROUNDING * (length(batch_frames[2u * b].xyz) + length(step) * float(1u << 30u));
    for (uint k = 1u; k < 3u; ++k) {
        float e = 0.5 * length(step * float(1u << (30u - 10u * k))) * (1.0 + ERROR_SLACK) + rounding;
        float z = u_perspective != 0.0 ? max(depth_min, u_projection.z - e) : 1.0;
        if (z > 0.0 && e * u_pixel_scale <= u_error_px * z) return k;
    }
    return 3u;
}
#endif

void main() {
    uint b;
    if (!range_index(u_batches, b)) return;
    float depth_min;
    bool shown = batch_in_view(b, depth_min);
#if ADAPTIVE
    batch_flags[b] = shown ? batch_levels(b, depth_min) : 0u;
#else
    batch_flags[b] = shown ? 3u : 0u;
#endif
}
