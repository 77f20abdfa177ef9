// The fill budget on the GPU (progressive/budget.py is the tested twin): stage
// BEGIN places the fixed first fill on the ring; stage ADAPT turns this frame's
// timestamps into the points that still fit and places them; stage GROW (a cold
// frame's, budget.grow) places growth stage u_grow at the rate of the stage before
// it. Each writes the range of its fill pieces and their indirect dispatch
// arguments. No CPU readback.
layout(local_size_x = 1) in;
#include "common.glsl"

layout(std430, binding = BINDING_FILL_STATE) buffer FillState { uint state[]; };
layout(std430, binding = BINDING_FILL_ARGS) writeonly buffer FillArgs { uint args[]; };
layout(std430, binding = BINDING_TIMESTAMPS) readonly buffer Timestamps { uint64_t stamps[]; };

uniform int u_stage;
uniform uint u_points;        // ring size: slots of the cloud
uniform uint u_first_fill;    // the configured first fill (or fixed budget), not capped by the cloud
uniform bool u_reset;         // the camera moved or points were added: count fills anew
uniform bool u_fixed;
uniform uint u_parity;        // this frame's timestamp block
uniform bool u_have_prev;     // the other block holds the previous frame
uniform uint u_goal_ns;
uniform uint u_min_budget;
uniform uint u_max_budget;
uniform uint u_batches;       // batches of the batched layout (0: none)
uniform uint u_grow;          // GROW: the growth stage, 1 or 2

const uint64_t VALID_NS = 4294967296ul;

// Not the clamp()/min() builtins: Mesa 22.3 crashes compiling them for uint64_t.
uint64_t clamp64(uint64_t v, uint64_t lo, uint64_t hi) {
    return v < lo ? lo : (v > hi ? hi : v);
}

void write_piece(uint piece, uint first, uint count) {
    state[STATE_PIECES + 2u * piece] = first;
    state[STATE_PIECES + 2u * piece + 1u] = count;
    uvec3 grid = dispatch_grid(count);
    args[3u * piece] = grid.x;
    args[3u * piece + 1u] = grid.y;
    args[3u * piece + 2u] = grid.z;
    // the same piece as DrawArraysIndirectCommand for the GL_POINTS baseline
    args[DRAW_ARGS_WORD + 4u * piece] = count;
    args[DRAW_ARGS_WORD + 4u * piece + 1u] = 1u;
    args[DRAW_ARGS_WORD + 4u * piece + 2u] = 0u;
    args[DRAW_ARGS_WORD + 4u * piece + 3u] = 0u;
    // the batch walk (raster_compute.comp BATCH_GROUPS): a group for each batch whose
    // slices meet the piece, consecutive slice indices modulo the batches
    uint walk = count == 0u || u_batches == 0u ? 0u
        : min(u_batches, (first + (count - 1u)) / SLICE_POINTS - first / SLICE_POINTS + 1u);
    uvec3 groups = dispatch_groups(walk);
    args[WALK_ARGS_WORD + 3u * piece] = groups.x;
    args[WALK_ARGS_WORD + 3u * piece + 1u] = groups.y;
    args[WALK_ARGS_WORD + 3u * piece + 2u] = groups.z;
}

// split_ring(): two contiguous pieces of [offset, offset+count) on the ring.
void place(uint piece, uint count) {
    uint n = u_points;
    uint offset = state[STATE_OFFSET];
    count = min(count, n);
    uint first = min(count, n - offset);
    write_piece(piece, offset, first);
    write_piece(piece + 1u, 0u, count - first);
    uint next = offset + count;          // < 2n; n < 2^32 but the sum may not be
    state[STATE_OFFSET] = (next < offset || next >= n) ? next - n : next;
    uint filled = state[STATE_FILLED];
    state[STATE_FILLED] = n - filled > count ? filled + count : n;
}

bool elapsed(uint64_t later, uint64_t earlier, out uint64_t d) {
    d = later - earlier;
    return d < VALID_NS;
}

void main() {
    uint base = u_parity * TIMESTAMP_SLOTS;
    if (u_stage == STAGE_BEGIN) {
        if (u_reset) state[STATE_FILLED] = 0u;
        for (uint k = 4u; k < FILL_PIECES; ++k) write_piece(k, 0u, 0u);     // a frame without growth stages
        uint next_first = state[STATE_NEXT_FIRST];
        uint known = next_first == 0u ? FIRST_INITIAL : next_first;
        uint first = min(u_fixed ? u_first_fill : min(known, u_first_fill), u_points);
        state[STATE_FIRST] = first;
        place(0u, first);
        return;
    }
    uint prev_base = (1u - u_parity) * TIMESTAMP_SLOTS;
    // the previous frame's time after its fill (prepare, resolve, effects) is reserved
    uint64_t reserved = 0ul;
    if (!(u_have_prev && elapsed(stamps[prev_base + TS_END], stamps[prev_base + TS_FILL_END], reserved))) reserved = 0ul;
    uint64_t goal = uint64_t(u_goal_ns);
    if (u_stage == STAGE_GROW) {
        uint start = base + (u_grow == 1u ? TS_FIRST_END : TS_GROW_1);
        uint end = base + (u_grow == 1u ? TS_GROW_1 : TS_GROW_2);
        uint stage_points = u_grow == 1u ? state[STATE_BUDGET] : state[STATE_STAGE_POINTS];
        uint64_t ns, spent;
        uint grown = 0u;
        if (!u_fixed && stage_points > 0u && elapsed(stamps[end], stamps[start], ns) && ns > 0ul
                && elapsed(stamps[end], stamps[base + TS_FRAME], spent)) {
            uint64_t left = spent + reserved < goal ? goal - spent - reserved : 0ul;
            uint64_t raw = clamp64(uint64_t(stage_points) * left / ns, 0ul, 281474976710656ul);
            raw = raw * uint64_t(state[STATE_GAIN]) / GAIN_ONE;
            uint so_far = state[STATE_BUDGET];
            uint frame_points = state[STATE_FRAME_POINTS];
            uint64_t room = uint64_t(min(u_max_budget > so_far ? u_max_budget - so_far : 0u,
                                         u_points > frame_points ? u_points - frame_points : 0u));
            grown = uint(raw < room ? raw : room);
        }
        state[STATE_STAGE_POINTS] = grown;
        state[STATE_BUDGET] += grown;
        state[STATE_FRAME_POINTS] += grown;
        place(2u + 2u * u_grow, grown);
        return;
    }
    uint budget = 0u;
    if (!u_fixed) {
        uint first_points = state[STATE_FIRST];
        uint64_t first_ns;
        bool first_timed = elapsed(stamps[base + TS_FIRST_END], stamps[base + TS_FILL], first_ns) && first_ns > 0ul;
        // the rate, as budget.measure: the previous fill's adaptive part and the first part's fixed cost
        uint64_t last_ns, last_first_ns, last_before_ns;
        bool last_fill = u_have_prev && elapsed(stamps[prev_base + TS_FILL_END], stamps[prev_base + TS_FILL], last_ns)
            && elapsed(stamps[prev_base + TS_FIRST_END], stamps[prev_base + TS_FILL], last_first_ns)
            && elapsed(stamps[prev_base + TS_FILL], stamps[prev_base + TS_FRAME], last_before_ns);
        if (last_fill) {
            uint points = state[STATE_FRAME_POINTS];
            uint first = state[STATE_FRAME_FIRST];
            if (points > 0u && last_ns > 0ul) {
                uint adaptive = points - first;
                uint64_t adaptive_ns = last_ns - last_first_ns;
                if (points >= first && adaptive >= first && last_ns > last_first_ns) {
                    uint64_t a = last_first_ns * uint64_t(adaptive);
                    uint64_t b = uint64_t(first) * adaptive_ns;
                    state[STATE_RATE_POINTS] = adaptive;
                    state[STATE_RATE_NS] = uint(adaptive_ns);
                    state[STATE_FIXED_NS] = uint((a - (b < a ? b : a)) / uint64_t(adaptive));
                } else {
                    state[STATE_RATE_POINTS] = points;
                    state[STATE_RATE_NS] = uint(last_ns);
                }
            }
        }
        // this frame's first fill less that cost: the view now, where it is slower
        if (first_points > 0u && first_timed) {
            if (state[STATE_RATE_NS] == 0u) {
                state[STATE_RATE_POINTS] = first_points;
                state[STATE_RATE_NS] = uint(first_ns);
            } else {
                uint64_t fixed_ns = uint64_t(state[STATE_FIXED_NS]);
                uint64_t now_ns = first_ns - (fixed_ns < first_ns ? fixed_ns : first_ns);
                if (now_ns * uint64_t(state[STATE_RATE_POINTS]) > uint64_t(state[STATE_RATE_NS]) * uint64_t(first_points)) {
                    state[STATE_RATE_POINTS] = first_points;
                    state[STATE_RATE_NS] = uint(now_ns);
                }
            }
        }
        uint64_t prev_ns;
        if (u_have_prev && elapsed(stamps[prev_base + TS_END], stamps[prev_base + TS_FRAME], prev_ns) && prev_ns > 0ul) {
            uint64_t ratio = clamp64(goal * GAIN_ONE / prev_ns, GAIN_STEP_MIN, GAIN_STEP_MAX);
            uint64_t half_step = (GAIN_ONE + ratio) / 2ul;
            uint64_t gain = clamp64(uint64_t(state[STATE_GAIN]) * half_step / GAIN_ONE, GAIN_MIN, GAIN_MAX);
            state[STATE_GAIN] = uint(gain);
        }
        uint64_t spent;
        bool valid = elapsed(stamps[base + TS_FIRST_END], stamps[base + TS_FRAME], spent);
        uint64_t left = valid && spent + reserved < goal ? goal - spent - reserved : 0ul;
        uint64_t raw = uint64_t(u_min_budget);
        if (state[STATE_RATE_NS] != 0u) {
            raw = clamp64(uint64_t(state[STATE_RATE_POINTS]) * left / uint64_t(state[STATE_RATE_NS]), 0ul, 281474976710656ul);
            raw = raw * uint64_t(state[STATE_GAIN]) / GAIN_ONE;
            // the previous frame's points scaled by the goal over its time (budget.step)
            if (last_fill && u_have_prev && prev_ns > 0ul && prev_ns < VALID_NS) {
                // budget.scaled_points
                uint64_t known = last_before_ns + uint64_t(state[STATE_FIXED_NS]);
                uint64_t whole = known >= prev_ns || known >= goal ? uint64_t(state[STATE_FRAME_POINTS]) * goal / prev_ns
                    : uint64_t(state[STATE_FRAME_POINTS]) * (goal - known) / (prev_ns - known);
                uint64_t cap = whole > uint64_t(first_points) ? whole - uint64_t(first_points) : 0ul;
                raw = raw < cap ? raw : cap;
            }
        }
        if (first_points > 0u && first_timed) {
            // the next first fill: a share of the goal at this one's own rate (budget.step)
            uint64_t share = uint64_t(first_points) * (goal / FIRST_SHARE) / first_ns;
            share = share < FIRST_MIN ? FIRST_MIN : share;
            state[STATE_NEXT_FIRST] = uint(share < uint64_t(u_first_fill) ? share : uint64_t(u_first_fill));
        }
        budget = uint(clamp64(raw, uint64_t(u_min_budget), uint64_t(u_max_budget)));
        uint first = state[STATE_FIRST];
        budget = min(budget, u_points > first ? u_points - first : 0u);
    }
    state[STATE_BUDGET] = budget;
    state[STATE_FRAME_FIRST] = state[STATE_FIRST];
    state[STATE_FRAME_POINTS] = state[STATE_FIRST] + budget;
    place(2u, budget);
}
