"""The adaptive fill budget (paper 3.4.1) as pure integer arithmetic.

Each frame fills a fixed first range, then as many more points as fit in the time
left at the fill rate measured from GPU timestamps. A first fill of a million points
takes microseconds on a large GPU, so its fixed costs (dispatches, the budget pass)
hide its rate; measured from it alone, only the gain's steps (about 11 % a frame) grew
the budget into the frame. So the previous frame's fill gives the rate and the first
fill's fixed cost (its adaptive part's time per point, and what the first fill took
beyond that), and this frame's first fill, less that fixed cost, shows whether the
view became dearer (a jump, a zoom out of a culled close-up): the rate is the slower
of the two. `shaders/budget.comp` runs the same arithmetic on the GPU (uint64
nanoseconds, no floats, so both agree exactly); this module is its tested twin. A
damped gain, corrected from the previous frame's total time, takes back what a frame
over the goal shows the rate missed, and returns to one.

The time after the fill is reserved as the previous frame took it, but it grows with
the fill where prepare gathers the new winners from a store of gigabytes (during
motion on the H200 at 1 B points, 2 ms after a fill of a million points and 20 ms
after one of a billion): a budget of the time left then alternated between the whole
cloud and nothing (bench/results/nvidia-h200/before_cap/progressive_1000000000.md). So a frame
also fills at most the previous frame's points scaled by the goal over its time (each
less the time known to be fixed): the points it would fill were the rest of its time
proportional to them, which approaches the goal from below without overshooting it,
and from above (a secant through zero of a time that grows with the points).

A cold frame (the renderer's first: no rate known) measures only its first fill, whose
fixed costs hide the rate: on the H200 at 1 B points the first frame filled 14 M points
in 0.87 ms, the next 183 M in 2.9 ms and the next 810 M in 13.3 ms, the rate growing
with the fill (fixed fills of 1 M points took 0.35 ms each;
bench/results/nvidia-h200/progressive_1000000000.json at 64481f5), so a still view took four
frames to be exact. So a cold frame adds GROW_STAGES stages
after its adaptive part, each filling the time left at the rate of the stage before it
(grow): each stage is larger, so its rate is nearer the true one.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

U64 = 2**64
VALID_NS = 2**32          # a difference above ~4.3 s (or negative, wrapped) is not a measurement
GAIN_ONE = 1024           # gain in 1/1024 units
GAIN_MIN, GAIN_MAX = 128, GAIN_ONE   # the gain only takes back: growth comes from the scaled points
GAIN_STEP_MIN, GAIN_STEP_MAX = 820, 1250   # at most -20 % / +22 % per frame
RAW_CAP = 2**48           # keeps raw budget x gain inside uint64 on the GPU
FIRST_MIN = 1024          # the measured first fill never shrinks below this
FIRST_INITIAL = 65_536    # before any measurement: small, the adaptive part adds the rest
FIRST_SHARE = 4           # ... nor takes more than 1/4 of the goal at the measured rate
GROW_STAGES = 2           # measured stages a cold frame adds after its adaptive part


@dataclass(frozen=True)
class BudgetParams:
    """target_ns: the whole frame; margin_q10: share of it kept free (1024 = all)."""

    target_ns: int = 16_666_667
    margin_q10: int = 154           # 15 %
    first_fill: int = 1_000_000     # points filled before measuring (the paper's 1M)
    min_budget: int = 0
    max_budget: int = 2**32 - 1
    fixed: int | None = None        # a fixed budget instead of the adaptive one

    @property
    def goal_ns(self) -> int:
        return self.target_ns * (1024 - self.margin_q10) // 1024

    def first(self, points: int, state: BudgetState | None = None) -> int:
        """Points in the first (measured) fill of a frame: the fixed budget, or the
        configured first fill, shrunk on slow devices so it stays a fraction of the goal."""
        if self.fixed is not None:
            return min(self.fixed, points)
        known = state.next_first if state is not None and state.next_first else FIRST_INITIAL
        return min(self.first_fill, known, points)


@dataclass(frozen=True)
class BudgetState:
    """What the GPU keeps between frames."""

    rate_points: int = 0        # last valid measurement: points ...
    rate_ns: int = 0            # ... in this many nanoseconds
    gain_q10: int = GAIN_ONE
    next_first: int = 0         # the next frame's first fill (0: the configured size)
    fixed_ns: int = 0           # the first fill's fixed cost, from the last frame that showed it


@dataclass(frozen=True)
class LastFill:
    """The previous frame's fill: points in all and in its first part, nanoseconds from
    its fill's start to the end of its first part and of all of it, and from its
    frame's start to its fill's."""

    points: int
    first: int
    ns: int
    first_ns: int
    before_ns: int = 0


def elapsed(later: int, earlier: int) -> int | None:
    """later - earlier for 64-bit timestamps that may wrap; None if not a plausible duration."""
    d = (later - earlier) % U64
    return d if d < VALID_NS else None


def step(t_frame: int, t_fill: int, t_first: int, prev_frame_ns: int | None, first_points: int,
         state: BudgetState, params: BudgetParams, prev_after_ns: int | None = None,
         prev_fill: LastFill | None = None) -> tuple[int, BudgetState]:
    """Points to fill after the first fill, and the state for the next frame.

    t_frame, t_fill, t_first: timestamps at frame start, fill start, first fill end.
    prev_frame_ns: the previous frame's GPU time; prev_after_ns: its time from the end
    of its fill to its end (prepare, resolve, effects); prev_fill: its fill; None when
    unknown (after frames without a fill: the rate and fixed cost kept stand in)."""
    if params.fixed is not None:
        return 0, state
    first_ns = elapsed(t_first, t_fill)
    state = measure(state, prev_fill, first_points, first_ns)
    goal = params.goal_ns
    if prev_frame_ns is not None and 0 < prev_frame_ns < VALID_NS:
        ratio = min(max(goal * GAIN_ONE // prev_frame_ns, GAIN_STEP_MIN), GAIN_STEP_MAX)
        half_step = (GAIN_ONE + ratio) // 2
        gain = min(max(state.gain_q10 * half_step // GAIN_ONE, GAIN_MIN), GAIN_MAX)
        state = replace(state, gain_q10=gain)
    spent = elapsed(t_first, t_frame)
    reserved = prev_after_ns if prev_after_ns is not None and 0 <= prev_after_ns < VALID_NS else 0
    left = goal - spent - reserved if spent is not None and spent + reserved < goal else 0
    if state.rate_ns == 0:
        budget = params.min_budget
    else:
        budget = min(state.rate_points * left // state.rate_ns, RAW_CAP) * state.gain_q10 // GAIN_ONE
        if prev_fill is not None and prev_frame_ns is not None and 0 < prev_frame_ns < VALID_NS:
            budget = min(budget, max(scaled_points(prev_fill, prev_frame_ns, state.fixed_ns, goal) - first_points, 0))
    if first_points > 0 and first_ns:
        # the next first fill: a share of the goal at this one's own rate, fixed costs and all
        # (a rate less them would grow a fill whose fixed costs exceed the share)
        share = first_points * (goal // FIRST_SHARE) // first_ns
        state = replace(state, next_first=min(params.first_fill, max(FIRST_MIN, share)))
    return min(max(budget, params.min_budget), params.max_budget), state


def grow(t_frame: int, t_start: int, t_end: int, stage_points: int, budget: int, frame_points: int, n: int,
         state: BudgetState, params: BudgetParams, prev_after_ns: int | None = None) -> int:
    """Points of a cold frame's next growth stage: the time left after the stage that ran
    from t_start to t_end (less the time after the fill, reserved as step reserves it)
    at that stage's own rate (its stage_points over its time), times the gain; within
    what max_budget leaves of the frame's adaptive `budget` so far and the ring's points
    the frame has not filled (n - frame_points); 0 where the stage was not timed."""
    if params.fixed is not None:
        return 0
    ns, spent = elapsed(t_end, t_start), elapsed(t_end, t_frame)
    if stage_points == 0 or not ns or spent is None:
        return 0
    reserved = prev_after_ns if prev_after_ns is not None and 0 <= prev_after_ns < VALID_NS else 0
    left = params.goal_ns - spent - reserved if spent + reserved < params.goal_ns else 0
    points = min(stage_points * left // ns, RAW_CAP) * state.gain_q10 // GAIN_ONE
    return min(points, max(params.max_budget - budget, 0), max(n - frame_points, 0))


def measure(state: BudgetState, prev: LastFill | None, first_points: int, first_ns: int | None) -> BudgetState:
    """The rate this frame's budget uses. The previous fill's adaptive part gives the
    reference rate and, with its first part, that part's fixed cost (none when the
    first part was quicker than its points at the reference rate). An adaptive part
    smaller than the first (none, where the frame had no time left) has fixed costs of
    its own: then the whole fill is the reference and the cost kept stands. Without a
    previous fill, the kept rate and cost stand in. This frame's first fill less that
    cost is the view's rate now: it replaces the reference where it is slower, or where
    there is none (then the first fill's time in full)."""
    if prev is not None and prev.points > 0 and prev.ns > 0:
        adaptive, adaptive_ns = prev.points - prev.first, prev.ns - prev.first_ns
        if adaptive >= prev.first and adaptive_ns > 0:
            over = prev.first_ns * adaptive - min(prev.first * adaptive_ns, prev.first_ns * adaptive)
            state = replace(state, rate_points=adaptive, rate_ns=adaptive_ns, fixed_ns=over // adaptive)
        else:
            state = replace(state, rate_points=prev.points, rate_ns=prev.ns)
    if first_points == 0 or not first_ns:
        return state
    if state.rate_ns == 0:
        return replace(state, rate_points=first_points, rate_ns=first_ns)
    now_ns = first_ns - min(state.fixed_ns, first_ns)
    if now_ns * state.rate_points > state.rate_ns * first_points:
        return replace(state, rate_points=first_points, rate_ns=now_ns)
    return state


def scaled_points(prev: LastFill, prev_frame_ns: int, fixed_ns: int, goal: int) -> int:
    """The points a frame fills were its time, less its known fixed part (before the fill
    and the first part's fixed cost), proportional to them: the previous frame's points
    times the goal over its time, each less that part."""
    fixed = prev.before_ns + fixed_ns
    if fixed >= prev_frame_ns or fixed >= goal:
        return prev.points * goal // prev_frame_ns
    return prev.points * (goal - fixed) // (prev_frame_ns - fixed)


def frame_fill(budget: int, first_points: int, n: int) -> int:
    """A frame fills each slot at most once: the adaptive part is capped at n - first."""
    return min(budget, max(n - first_points, 0))


def split_ring(offset: int, count: int, n: int) -> tuple[tuple[int, int], tuple[int, int], int]:
    """[offset, offset+count) on a ring of n slots as two contiguous pieces (the second
    starts at 0 when it wraps) and the next offset. count is capped at n."""
    if n == 0:
        return (0, 0), (0, 0), 0
    count = min(count, n)
    first = min(count, n - offset)
    return (offset, first), (0, count - first), (offset + count) % n
