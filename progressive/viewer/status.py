"""The panel's status text, apart from imgui: the lines need no window, so the stats
tests check them wherever the viewer's libraries are missing (the GPU machine)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from progressive.loaders.copc import CopcStatus

if TYPE_CHECKING:
    from progressive.streaming import StreamStatus


def copc_lines(c: CopcStatus, streamed: bool = False) -> list[str]:
    """The Files section's lines of a COPC file: what its octree keeps on the GPU of its
    own (streamed: stream_lines say it of the whole cloud), what has been read, over
    HTTP what has been fetched (the network's share of a slow load), the damaged nodes
    skipped."""
    kept = [] if streamed else [f"    COPC levels {c.levels_kept} / {c.levels}, nodes {c.nodes_kept:,} / {c.nodes:,}",
                                f"    points {c.points_kept:,} / {c.points:,} kept"]
    lines = [*kept, f"    read {c.nodes_read:,} nodes, {c.bytes_read / 2**20:,.1f} MiB"]
    if c.requests or c.requests_in_flight:
        lines.append(f"    fetched {c.bytes_fetched / 2**20:,.1f} MiB in {c.requests:,} requests, "
                     f"{c.requests_in_flight} in flight")
    if c.nodes_skipped:
        lines.append(f"    {c.nodes_skipped:,} damaged nodes skipped ({c.points_skipped:,} points)")
    return lines


def stream_lines(s: StreamStatus) -> list[str]:
    """A streamed cloud's lines: the nodes on the GPU for the view, those on their way,
    and whether the view has all it will get."""
    lines = [f"streaming COPC nodes: {s.resident_nodes:,} / {s.nodes:,} on the GPU",
             f"    points {s.resident_points:,} / {s.points:,} (room for {s.capacity_points:,})",
             f"    {s.loading_nodes:,} loading, {s.held_nodes:,} waiting, {s.evicted_nodes:,} evicted"
             + (f", {s.failed_nodes:,} failed" if s.failed_nodes else "")]
    lines.append("    the view's nodes are all on the GPU" + (f" (down to {s.finest_px:g} px)" if s.finest_px else "")
                 if s.settled else
                 "    reading the view's nodes" + (f" (detail of {s.missing_px:.1f} px still missing)"
                                                    if math.isfinite(s.missing_px) else ""))
    return lines
