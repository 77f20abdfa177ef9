"""Converting to COPC (loaders/copc_write.py, what `progressive convert IN OUT.copc.laz`
runs): seconds and peak memory of the octree built in memory and out of core, each in a
fresh process, GPU-free, for the sample tiled to N points as LAS or LAZ; where both
builds run, their hierarchies are checked to hold the same nodes with the same point
counts (tests/test_copc.py compares the points themselves)."""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench.report import RunInfo, Table


def child(source: str, out: str, memory_points: int | None, scratch: str) -> dict:
    """One convert in this process: its seconds, peak resident memory and what it wrote."""
    from progressive.loaders import copc_write

    t0 = time.perf_counter()
    with open(out, "w+b") as stream:
        written = copc_write.write_copc(stream, [source], memory_points=memory_points, scratch=scratch)
    seconds = time.perf_counter() - t0
    return {"seconds": seconds, "peak_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            "points": written.points, "nodes": written.nodes, "levels": written.levels,
            "bytes": Path(out).stat().st_size}


def node_table(path: str) -> list[tuple]:
    """The hierarchy's (level, x, y, z, point count) of every node, sorted."""
    from progressive.loaders.copc import open_copc

    h = open_copc(path).hierarchy
    return sorted(zip(*(a.tolist() for a in (h.nodes["level"], h.nodes["x"], h.nodes["y"], h.nodes["z"],
                                             h.nodes["point_count"]))))


BUILDS = ("in memory", "out of core")


def run(points: int, memory_points: int, cache: Path | None = None, compress: bool = False,
        builds: tuple[str, ...] = BUILDS, scratch: Path | None = None) -> Table:
    """memory_points 0: the out-of-core build's own limits (copc_write.build_limit);
    scratch: where its scratch goes (default beside the output)."""
    from bench import data
    from progressive.loaders.copc_write import IN_MEMORY_POINTS

    if not memory_points and "out of core" in builds and points <= IN_MEMORY_POINTS:
        raise ValueError(f"with its own limits convert builds {points:,} points in memory: give --memory-points")
    source = data.tiled(points, compress, cache or data.CACHE)
    table = Table("convert", "COPC written in memory and out of core", f"{source.name}", f"{points:,}",
                  ("build", "memory points", "seconds", "M points/s", "peak MiB", "nodes", "levels", "MiB written"))
    raw, tables = [], []
    with tempfile.TemporaryDirectory(prefix="convert-", dir=source.parent) as folder:
        for label, limit in ((b, points if b == "in memory" else memory_points) for b in builds):
            out = str(Path(folder) / f"{label.replace(' ', '_')}.copc.laz")
            done = subprocess.run([sys.executable, "-m", "bench.convert", "--child", str(source), out,
                                   str(limit or 0), str(scratch or folder)], capture_output=True, text=True, check=True)
            r = json.loads(done.stdout.strip().splitlines()[-1])
            tables.append(node_table(out))
            shown = "" if label == "in memory" else f"{limit:,}" if limit else "half the free memory"
            table.rows.append((label, shown, round(r["seconds"], 2),
                               round(r["points"] / r["seconds"] / 1e6, 2), round(r["peak_mib"]), r["nodes"],
                               r["levels"], round(r["bytes"] / 2**20, 1)))
            raw.append({"build": label, "memory_points": limit, **r})
    if len(tables) == 2 and tables[0] != tables[1]:
        raise AssertionError("the octree built out of core has other nodes than the one built in memory")
    where = f"in {scratch} (files there in memory are not in the peak)" if scratch else "beside the output"
    table.notes = [f"Each build a fresh `python` process converting {source.name}; peak MiB: its peak "
                   f"resident memory (getrusage). Out of core: the cubes' scratch files {where}."
                   + (" Both files' hierarchies were checked to hold the same nodes with the same point counts."
                      if len(tables) == 2 else "")]
    table.raw = {"rows": raw}
    return table


def main(argv=None) -> int:
    if argv is None and len(sys.argv) == 6 and sys.argv[1] == "--child":
        source, out, limit, scratch = sys.argv[2], sys.argv[3], int(sys.argv[4]), sys.argv[5]
        print(json.dumps(child(source, out, limit or None, scratch)))
        return 0
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=12_000_000)
    ap.add_argument("--memory-points", type=int, default=2_000_000,
                    help="the out-of-core build's limit (0: its own, half the free memory)")
    ap.add_argument("--scratch", type=Path, help="where the out-of-core scratch goes (default beside the output; "
                                                 "about 48 bytes a point: /dev/shm at 1 B points)")
    ap.add_argument("--laz", action="store_true", help="convert the tiled sample as LAZ (default LAS)")
    ap.add_argument("--builds", nargs="+", choices=BUILDS, default=list(BUILDS),
                    help="one build only where the other does not fit (in memory at 1 B points)")
    ap.add_argument("--cache", type=Path, help="where the tiled file is made (default bench/.cache)")
    ap.add_argument("--machine", default="local", help="the results folder's name (no GPU is asked)")
    ap.add_argument("--out", default="bench/results")
    args = ap.parse_args(argv)
    table = run(args.points, args.memory_points, args.cache, args.laz, tuple(args.builds), args.scratch)
    table.publish(RunInfo.cpu_only("convert only", args.machine), None, Path(args.out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
