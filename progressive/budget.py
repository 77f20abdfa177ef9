"""The adaptive fill budget (paper 3.4.1) as pure integer arithmetic.

Each frame fills a fixed first range, measures its rate from GPU timestamps, and
fills as many more points as fit in the time left. `shaders/budget.comp` runs the
same arithmetic on the GPU (uint64 nanoseconds, no floats, so both agree exactly);
this module is its tested twin. A damped gain, corrected from the previous frame's
total time, absorbs what the first-fill rate does not see (prepare, resolve, the
32-bit path's second pass) without oscillating.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

U64 = 2**64
VALID_NS = 2**32          # a difference above ~4.3 s (or negative, wrapped) is not a measurement
GAIN_ONE = 1024           # gain in 1/1024 units
GAIN_MIN, GAIN_MAX = 128, 8192
GAIN_STEP_MIN, GAIN_STEP_MAX = 820, 1250   # at most -20 % / +22 % per frame
RAW_CAP = 2**48           # keeps raw budget x gain inside uint64 on the GPU
FIRST_MIN = 1024          # the measured first fill never shrinks below this
FIRST_INITIAL = 65_536    # before any measurement: small, the adaptive part adds the rest
FIRST_SHARE = 4           # ... nor takes more than 1/4 of the goal at the measured rate


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


def elapsed(later: int, earlier: int) -> int | None:
    """later - earlier for 64-bit timestamps that may wrap; None if not a plausible duration."""
    d = (later - earlier) % U64
    return d if d < VALID_NS else None


def step(t_frame: int, t_fill: int, t_first: int, prev_frame_ns: int | None, first_points: int,
         state: BudgetState, params: BudgetParams, prev_after_ns: int | None = None) -> tuple[int, BudgetState]:
    """Points to fill after the first fill, and the state for the next frame.

    t_frame, t_fill, t_first: timestamps at frame start, fill start, first fill end.
    prev_frame_ns: the previous frame's GPU time; prev_after_ns: its time from the end
    of its fill to its end (prepare, resolve, effects); None when unknown."""
    if params.fixed is not None:
        return 0, state
    fill_ns = elapsed(t_first, t_fill)
    if first_points > 0 and fill_ns:
        state = replace(state, rate_points=first_points, rate_ns=fill_ns)
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
        share = state.rate_points * (goal // FIRST_SHARE) // state.rate_ns
        state = replace(state, next_first=min(params.first_fill, max(FIRST_MIN, share)))
    return min(max(budget, params.min_budget), params.max_budget), state


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
