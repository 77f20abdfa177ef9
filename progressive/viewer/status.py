"""The panel's status text, apart from imgui: the lines need no window, so the stats
tests check them wherever the viewer's libraries are missing (the GPU machine)."""

from __future__ import annotations

from progressive.loaders.copc import CopcStatus


def copc_lines(c: CopcStatus) -> list[str]:
    """The Files section's lines of a COPC file: what its octree keeps on the GPU of its
    own, what has been read, over HTTP what has been fetched (the network's share of a
    slow load), the damaged nodes skipped."""
    lines = [f"    COPC levels {c.levels_kept} / {c.levels}, nodes {c.nodes_kept:,} / {c.nodes:,}",
             f"    points {c.points_kept:,} / {c.points:,} kept",
             f"    read {c.nodes_read:,} nodes, {c.bytes_read / 2**20:,.1f} MiB"]
    if c.requests or c.requests_in_flight:
        lines.append(f"    fetched {c.bytes_fetched / 2**20:,.1f} MiB in {c.requests:,} requests, "
                     f"{c.requests_in_flight} in flight")
    if c.nodes_skipped:
        lines.append(f"    {c.nodes_skipped:,} damaged nodes skipped ({c.points_skipped:,} points)")
    return lines
