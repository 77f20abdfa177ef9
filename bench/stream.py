"""Streaming COPC (issue 15): a COPC file many times larger than a GPU memory limit,
opened streamed (SessionOptions(stream=Streaming.ON)) and driven frame by frame as a
viewer drives it. From a local file, then over HTTP from a range server on 127.0.0.1:
the time to the first image and until the overview is settled (every node it needs
resident) and converged (the still image exact); then a camera path of three legs
(a zoom from the overview into a close-up of one corner, a fly along that edge, a zoom
back out), each timed per frame (the wall time of Session.frame: on llvmpipe the GPU is
the CPU, and the frame loop's pacing waits for it, so this is what a user feels) and
followed by the time its still end view takes to settle and converge. The file is the
bundled sample tiled to N points (bench/data.py) and converted once, cached.

    python -m bench.stream [--points 20000000] [--limit 64M] [--size 640x360] [--frames 60]

writes bench/results/<machine>/stream.{md,json}."""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from bench.data import CACHE, write_tiled
from bench.report import RunInfo, Table
from bench.startup import frame_until_first_image
from bench.synthetic import SAMPLE
from progressive import memory
from progressive.camera import Camera
from progressive.cli import bytes_arg, detail_arg
from progressive.loaders.copc import open_copc
from progressive.loaders.copc_residency import Status
from progressive.loaders.copc_write import write_copc
from progressive.loaders.http import REQUESTS_IN_FLIGHT, HttpOptions
from progressive.loaders.las import selection
from progressive.loaders.laz import decode_chunks
from progressive.loaders.records import RECORD_BYTES
from progressive.loaders.types import BATCH_POINTS, available_cores
from progressive.session import Session, SessionOptions, Streaming
from progressive.streaming import FINEST_PX, WRITE_SECONDS, WRITE_STILL_SECONDS

RESULTS = Path(__file__).resolve().parent / "results"
TESTS = Path(__file__).resolve().parents[1] / "tests"
POINTS = 20_000_000
"""The issue's target on this machine: a 20 M-point COPC file with a LIMIT GPU memory limit."""
LIMIT = "64M"
SIZE = "640x360"
"""An image whose per-pixel buffers take a quarter of LIMIT, leaving room for points."""
LEG_FRAMES = 60
"""Frames of camera motion per leg of the path."""
STILL_SECONDS = 300.0
"""Longest a still view is given to settle and converge before the bench gives up on it."""
CORNER = 0.05
"""The close-up's target: this share of the cloud's X and Y extent in from its lowest corner."""
CLOSE = 0.04
"""The close-up's distance from its target, a share of the cloud's larger horizontal extent."""
FLY = 0.3
"""How far the fly leg moves along X, a share of the cloud's X extent."""
NEAR = 0.01
"""A moving camera's near plane, a share of its distance to its target."""
DETAIL_PX = 1.0
"""A still view's detail counts as there once every node it keeps with points this far
apart on screen (or farther) is shown."""
NAME = "cloud.copc.laz"
"""The file's name on the range server."""
FIELDS = ("seconds", "resident_nodes", "resident_points", "loading_nodes", "held_nodes", "evicted_nodes",
          "settled", "converged", "missing_px", "frame", "stream_s", "issue_s")
"""What is recorded of each frame (raw JSON, a list per field): frame is the renderer's
index (its GPU record joins it after the leg), stream_s and issue_s Session.host's parts."""
CEILING_POINTS = 20_000_000
"""Most points of the file the decode ceiling (decode_rate) decodes."""
SLOW_MS = 1e3 / 60
"""A moving frame slower than this missed the viewer's frame target (BudgetParams.target_ns)."""


@dataclass(frozen=True)
class Built:
    """The cached COPC file and what converting it took (its sidecar JSON keeps it)."""

    path: Path
    points: int
    nodes: int
    levels: int
    bytes: int
    tile_seconds: float       # the tiled LAS or LAZ written (0 where it was there already)
    convert_seconds: float    # loaders/copc_write.write_copc, as `progressive convert` runs it
    cached: bool              # this run found it built


def build(points: int, cache: Path = CACHE, compress: bool = False, scratch: Path | None = None) -> Built:
    """The sample tiled to `points` as LAS, or LAZ with `compress` (bench/data.py, shared
    with the other benches; LAZ where a LAS would not fit the disk beside the scratch of
    an out-of-core convert), converted to COPC once (its scratch in `scratch`, default
    `cache`: about 48 bytes a point, so at 1 B points /dev/shm where the disk is short);
    the source is removed again where this made it."""
    cache.mkdir(parents=True, exist_ok=True)
    stem = cache / f"{SAMPLE.stem}_x{points}"
    path, sidecar = stem.with_suffix(".copc.laz"), stem.with_suffix(".copc.json")
    if path.exists() and sidecar.exists():
        return Built(**{**json.loads(sidecar.read_text()), "path": path, "cached": True})
    source = stem.with_suffix(".laz" if compress else ".las")
    made = not source.exists()
    t0 = time.perf_counter()
    if made:
        write_tiled(SAMPLE, source, points, compress=compress)
    t1 = time.perf_counter()
    tmp = path.with_suffix(".tmp")
    with open(tmp, "w+b") as stream:
        written = write_copc(stream, [str(source)], scratch=scratch or cache)
    convert = time.perf_counter() - t1
    tmp.replace(path)
    if made:
        source.unlink()
    built = Built(path, written.points, written.nodes, written.levels, path.stat().st_size, t1 - t0, convert, False)
    sidecar.write_text(json.dumps({k: v for k, v in asdict(built).items() if k not in ("path", "cached")}))
    return built


def between(a: Camera, b: Camera, t: float) -> Camera:
    """The camera a share `t` of the way from a to b: the target moves straight, the
    distance to it geometrically (a zoom at an even pace on screen), the direction blends."""
    ta, tb = np.asarray(a.target), np.asarray(b.target)
    oa, ob = np.subtract(a.position, a.target), np.subtract(b.position, b.target)
    da, db = float(np.linalg.norm(oa)), float(np.linalg.norm(ob))
    direction = (1 - t) * oa / da + t * ob / db
    distance = da ** (1 - t) * db ** t
    target = ta + (tb - ta) * t
    position = target + direction / np.linalg.norm(direction) * distance
    return Camera(tuple(position.tolist()), tuple(target.tolist()), a.up, a.fov_y_deg,
                  near=a.near ** (1 - t) * b.near ** t, far=max(a.far, b.far))


def legs(overview: Camera, lo: np.ndarray, hi: np.ndarray, frames: int) -> list[tuple[str, list[Camera]]]:
    """The path: zoom into the corner near `lo`, fly along X, zoom back out to the overview."""
    extent = hi - lo
    target = lo + extent * np.array([CORNER, CORNER, 0.5])
    distance = CLOSE * float(max(extent[0], extent[1]))
    eye = target + np.array([0.0, -1.0, 1.0]) / np.sqrt(2) * distance
    near = Camera(tuple(eye.tolist()), tuple(target.tolist()), overview.up, overview.fov_y_deg,
                  near=NEAR * distance, far=overview.far)
    shift = np.array([FLY * extent[0], 0.0, 0.0])
    along = Camera(tuple((eye + shift).tolist()), tuple((target + shift).tolist()), near.up, near.fov_y_deg,
                   near.near, near.far)
    steps = [(k + 1) / frames for k in range(frames)]
    return [("zoom in", [between(overview, near, t) for t in steps]),
            ("fly along", [between(near, along, t) for t in steps]),
            ("zoom out", [between(along, overview, t) for t in steps])]


def record(s: Session, frame: int, seconds: float, log: dict[str, list]) -> None:
    st = s.status().stream
    values = {"seconds": seconds, "converged": s.converged, "frame": frame, "stream_s": s.host.stream_s,
              "issue_s": s.host.issue_s, **{k: getattr(st, k) for k in FIELDS if hasattr(st, k)}}
    for k in FIELDS:
        log[k].append(values[k])


def timed_frame(s: Session, camera: Camera, log: dict[str, list]) -> None:
    frame = s.status().frames
    t0 = time.perf_counter()
    s.frame(camera)
    record(s, frame, time.perf_counter() - t0, log)


def gpu_ms(s: Session, log: dict[str, list]) -> list[float | None]:
    """Each logged frame's GPU time from its first stamp to its last (None: a frame that
    ran no fill); waits for the GPU, so only once a leg is over."""
    frames = {f.frame: f.gpu_ms.get("frame") for f in s.stats()}
    return [frames.get(f) for f in log["frame"]]


def hold(s: Session, camera: Camera, since: float, log: dict[str, list], limit_s: float) -> dict:
    """Frames of a still `camera` until the view is settled and converged; seconds from
    `since` to each, and to the frame by which every node it keeps whose points lie
    DETAIL_PX apart on screen or more was shown (None: not within `limit_s`)."""
    detailed = settled = converged = None
    frames = 0
    while time.perf_counter() - since < limit_s:
        timed_frame(s, camera, log)
        frames += 1
        now = time.perf_counter() - since
        if detailed is None and log["missing_px"][-1] < DETAIL_PX:
            detailed = now
        if settled is None and log["settled"][-1]:
            settled = now
        if log["settled"][-1] and log["converged"][-1]:
            converged = now
            break
    return {"detailed_s": detailed, "settled_s": settled, "converged_s": converged, "still_frames": frames}


def parts(log: dict[str, list], moving: int) -> dict:
    """Where the time of a leg's moving frames (the overview: every frame) went: p95 of
    the host's node update and GPU issue, and of the GPU's frame; the median of each over
    the frames slower than SLOW_MS, and how many those were."""
    n = moving or len(log["seconds"])
    ms = {name: np.array(log[k][:n], dtype=float) * 1e3
          for name, k in (("frame", "seconds"), ("update", "stream_s"), ("issue", "issue_s"))}
    ms["gpu"] = np.array([np.nan if g is None else g for g in log["gpu_ms"][:n]], dtype=float)
    slow = ms["frame"] > SLOW_MS

    def pick(values: np.ndarray, q: float) -> float | None:
        values = values[~np.isnan(values)]
        return float(np.percentile(values, q)) if values.size else None

    out = {f"{k}_ms_p95": pick(v, 95) for k, v in ms.items() if k != "frame"}
    out |= {f"slow_{k}_ms_p50": pick(v[slow], 50) for k, v in ms.items()}
    return out | {"slow_frames": int(slow.sum())}


def summary(log: dict[str, list], moving: int, before_evicted: int) -> dict:
    """A leg's frame times (its moving frames; the overview: every frame) and node counts."""
    ms = np.array(log["seconds"][:moving] or log["seconds"]) * 1e3
    return {"frames": moving, "frame_ms_p50": float(np.percentile(ms, 50)),
            "frame_ms_p95": float(np.percentile(ms, 95)), "frame_ms_max": float(ms.max()), **parts(log, moving),
            "still_frame_ms_max": float(max(log["seconds"][moving:], default=0.0) * 1e3),
            "resident_nodes": log["resident_nodes"][-1], "resident_points": log["resident_points"][-1],
            "loading_max": max(log["loading_nodes"]), "held_max": max(log["held_nodes"]),
            "evicted": log["evicted_nodes"][-1] - before_evicted}


def fetched(s: Session) -> dict:
    """The file's counts so far: nodes read (again, where evicted before) and, over HTTP, fetched."""
    c = s.status().copc[0]
    return {"nodes_read": c.nodes_read, "bytes_read": c.bytes_read, "bytes_fetched": c.bytes_fetched,
            "requests": c.requests}


def writing(run: dict) -> tuple[float, float]:
    """Median ms of the frames that changed the store (nodes written or evicted), and of the others."""
    logs = [leg["log"] for leg in run["legs"]]
    ms = np.concatenate([log["seconds"] for log in logs]) * 1e3
    points, evicted = (np.concatenate([log[k] for log in logs]) for k in ("resident_points", "evicted_nodes"))
    changed = np.r_[True, (points[1:] != points[:-1]) | (evicted[1:] != evicted[:-1])]
    return float(np.median(ms[changed])), float(np.median(ms[~changed]))


def stream(source: str, options: SessionOptions, frames: int, limit_s: float) -> dict:
    """One streamed session through the overview and the path's legs."""
    opened = time.perf_counter()
    with Session([source], options) as s:
        overview = s.auto_camera()
        log = {k: [] for k in FIELDS}
        still = hold(s, overview, opened, log, limit_s)
        log["gpu_ms"] = gpu_ms(s, log)
        legs_out = [{"leg": "overview", **summary(log, 0, 0), **still, **fetched(s), "log": log}]
        status = s.status().stream
        capacity, first_image = status.capacity_points, s.first_image_seconds
        for name, cameras in legs(overview, s.info.bounds_min, s.info.bounds_max, frames):
            before = log["evicted_nodes"][-1]
            log = {k: [] for k in FIELDS}
            for camera in cameras:
                timed_frame(s, camera, log)
            still = hold(s, cameras[-1], time.perf_counter(), log, limit_s)
            log["gpu_ms"] = gpu_ms(s, log)
            legs_out.append({"leg": name, **summary(log, len(cameras), before), **still, **fetched(s), "log": log})
        end = s.status()
        state = s.streamer.state
        used = int(state.cost[state.status == Status.RESIDENT].sum())
        return {"batches": [used, state.capacity, state.store_batch_points], "source": source, "first_image_s": first_image, "startup": dict(s.startup), "capacity_points": capacity,
                "nodes": end.stream.nodes, "on_gpu": end.on_gpu, "resident_points": end.stream.resident_points,
                "failed_nodes": end.stream.failed_nodes, "warnings": s.warnings, "legs": legs_out,
                "names": list(s.streamer.reader.names), "device": s.glc.caps}


def decode_rate(path: Path, names: tuple[str, ...], points: int) -> dict:
    """lazrs on every core alone over the file's first `points` points, decoding the
    layers of `names` (what the stream's nodes were read with): the decode ceiling a
    streamed view's reads stand under, measured beside them. Points/s is None where the
    file's chunks cannot be decoded in parallel (no sound chunk table)."""
    source = open_copc(path)
    cores = available_cores()
    t0 = time.perf_counter()
    decoded = sum(len(r) for r in decode_chunks(str(path), source.laz, points, points, source.records.dtype, cores,
                                                 selection(names)))
    seconds = time.perf_counter() - t0
    return {"points": decoded, "seconds": seconds, "cores": cores, "names": list(names),
            "points_per_s": decoded / seconds if decoded else None}


def decode_note(ceiling: dict, overview_points: int) -> str:
    """What decode_rate found, and the least time the overview's resident points take at it."""
    layers = ", ".join(ceiling["names"]) or "no attribute"
    if ceiling["points_per_s"] is None:
        return "Decode ceiling: not measured (the file's chunks cannot be decoded in parallel)."
    rate = ceiling["points_per_s"]
    return (f"Decode ceiling, measured after the runs: lazrs alone on {ceiling['cores']} cores "
            f"(decompress_points_with_chunk_table over the file's first {ceiling['points']:,} points, positions and "
            f"{layers}, the layers the stream read) decoded {rate / 1e6:.1f} M points/s. At that rate the "
            f"{overview_points:,} points the file's overview held take {overview_points / rate:.2f} s to decode: no "
            f"stream of this file settles that view sooner, whatever its writes and plans cost.")


def warm_up(source: str, options: SessionOptions) -> dict:
    """One streamed session opened on `source` until its first image, then closed: the
    programs the streamed path needs compiled into the program cache, so that both
    measured sources start as a viewer's second run does (the first run in the H200's
    first table spent 2.66 s compiling); its first image and startup phases reported."""
    with Session([source], options) as s:
        frame_until_first_image(s, s.auto_camera(), source)
        return {"first_image_s": s.first_image_seconds, "startup": dict(s.startup)}


def served(path: Path, options: SessionOptions, frames: int, limit_s: float, latency_s: float = 0.0) -> dict:
    """The same over HTTP from tests/range_server.py's RangeServer on 127.0.0.1 (python's
    own http.server answers no ranges), in a process of its own as a real server would
    be, each answer `latency_s` late (a round trip to a server farther away); the
    server's counts beside the client's."""
    sys.path.insert(0, str(TESTS))
    from range_server import RangeServerProcess

    with RangeServerProcess({NAME: path}, latency_s) as server:
        out = stream(server.url(NAME), options, frames, limit_s)
        out["server_requests"], out["server_bytes"] = server.counts()
    return out


COLUMNS = ("source", "leg", "moving frames", "frame ms p50", "frame ms p95", "frame ms max", "update ms p95",
           "issue ms p95", "GPU ms p95", "slow frames", "slow: update ms", "slow: issue ms", "slow: GPU ms", "first image s",
           "1 px detail s", "settled s", "converged s", "still frames", "still frame ms max", "resident nodes", "resident points",
           "loading max", "evicted", "nodes read", "MB fetched", "requests")


def rows(label: str, run: dict) -> list[tuple]:
    """A row per leg; the first image on the overview's, what was fetched on HTTP's."""
    out, remote = [], label.startswith("HTTP")
    for leg in run["legs"]:
        over = leg["leg"] == "overview"
        out.append((label, leg["leg"], leg["frames"], leg["frame_ms_p50"], leg["frame_ms_p95"], leg["frame_ms_max"],
                    leg["update_ms_p95"], leg["issue_ms_p95"], leg["gpu_ms_p95"], leg["slow_frames"],
                    leg["slow_update_ms_p50"], leg["slow_issue_ms_p50"], leg["slow_gpu_ms_p50"],
                    run["first_image_s"] if over else None, leg["detailed_s"], leg["settled_s"], leg["converged_s"],
                    leg["still_frames"], leg["still_frame_ms_max"], leg["resident_nodes"], leg["resident_points"],
                    leg["loading_max"], leg["evicted"], leg["nodes_read"],
                    leg["bytes_fetched"] / 2**20 if remote else None, leg["requests"] if remote else None))
    return out


def run(points: int, limit: int, size: tuple[int, int], frames: int, cache: Path = CACHE,
        limit_s: float = STILL_SECONDS, compress: bool = False, scratch: Path | None = None,
        requests: tuple[int, ...] = (REQUESTS_IN_FLIGHT,), latency_s: float = 0.0,
        detail_px: float = FINEST_PX) -> tuple[Table, RunInfo]:
    load_before = os.getloadavg()[0]
    built = build(points, cache, compress, scratch)
    width, height = size
    options = SessionOptions(width=width, height=height, stream=Streaming.ON, gpu_memory_limit=limit,
                             stream_detail_px=detail_px)
    warm = warm_up(str(built.path), options)
    local = stream(str(built.path), options, frames, limit_s)
    remotes = {(f"HTTP {n}" if len(requests) > 1 else "HTTP"): served(
        built.path, replace(options, http=HttpOptions(in_flight=n)), frames, limit_s, latency_s) for n in requests}
    runs = {"file": local, **remotes}
    ceiling = decode_rate(built.path, tuple(local["names"]), min(built.points, CEILING_POINTS))
    load_after = os.getloadavg()[0]
    caps = local.pop("device")
    for remote in remotes.values():
        remote.pop("device")
    pixel_bytes = width * height * memory.PIXEL_BYTES
    staging = BATCH_POINTS * RECORD_BYTES
    table = Table("stream", "Streaming COPC: a file larger than the GPU memory limit, by level of detail",
                  f"{SAMPLE.name} tiled, converted to COPC ({built.nodes:,} nodes, {built.levels} levels, "
                  f"{built.bytes / 2**20:.0f} MiB)", f"{built.points:,}", COLUMNS)
    table.rows = [row for label, r in runs.items() for row in rows(label, r)]
    convert = (f"converted in {built.convert_seconds:.1f} s (loaders/copc_write.write_copc, what `progressive "
               f"convert IN OUT.copc.laz` runs; the tiled LAS written in {built.tile_seconds:.1f} s before)")
    ends = ", ".join(f"{label} {r['legs'][-1]['resident_nodes']:,} nodes resident" for label, r in runs.items())
    medians = {label: writing(r) for label, r in runs.items()}
    changes = " and ".join(f"{m[0]:.0f} ms ({label})" for label, m in medians.items())
    others = " and ".join(f"{m[1]:.0f} ms" for m in medians.values())
    used, batches, batch_points = local["batches"]
    filled = local["resident_points"] / (used * batch_points) if used else 0.0     # nothing came: said below
    unsettled = [f"{label} {leg['leg']}" for label, r in runs.items() for leg in r["legs"]
                 if leg["converged_s"] is None]
    table.notes = [
        (f"{built.points:,} points: bench/data.py's tiling of the bundled sample (raw-integer copies shifted by whole "
         f"tiles, every attribute real), {convert}{', cached from an earlier run' if built.cached else ''}. "
         f"Image {width}x{height}, GPU memory limit {limit / 2**20:.0f} MiB: the per-pixel buffers take "
         f"{pixel_bytes / 2**20:.1f} MiB ({memory.PIXEL_BYTES} bytes a pixel, progressive/memory.py), staging "
         f"{staging / 2**20:.1f} MiB, which leaves the store {local['capacity_points']:,} points in whole batches "
         f"({local['capacity_points'] / built.points:.1%} of the cloud). A view reads no node whose points lie "
         f"closer than {detail_px:g} px on screen (SessionOptions.stream_detail_px"
         f"{'' if detail_px else ': 0, nodes until the memory is full'})."),
        (f"Each source is one session (SessionOptions(stream=Streaming.ON, gpu_memory_limit=...)) driven as a viewer "
         f"drives it: Session.frame with the camera, never waiting for a node. Overview: the auto camera from open; "
         f"its settled and converged seconds count from the session's open (the first image too, "
         f"Session.first_image_seconds; both sources after a session opened on the file until its first image "
         f"and closed, which filled the program cache: that first session's first image took "
         f"{warm['first_image_s']:.2f} s, {warm['startup'].get('programs', 0):.2f} s of it programs) and its frame times are over every frame until converged. Then {frames} "
         f"moving frames per leg: a zoom from the overview to a close-up of the corner near the cloud's lowest X and "
         f"Y ({CORNER:.0%} in, at {CLOSE:.0%} of its extent), a fly {FLY:.0%} of the X extent along that edge, a zoom "
         f"back out to the overview; the camera then stops, and 1 px detail / settled / converged count from that "
         f"stop (1 px detail: every node the view keeps whose points lie {DETAIL_PX:g} px apart on screen or more is "
         f"shown, StreamStatus.missing_px < {DETAIL_PX:g}, what is left only deciding which point of a pixel is in "
         f"front; settled: nothing more to read or write for the view; converged: settled and the still image exact, "
         f"Session.converged). Frame ms: wall time of Session.frame over the moving frames (the frame loop paces "
         f"itself against the GPU, which on llvmpipe is the CPU); still frame ms max: the longest frame of the "
         f"stop. Update and issue ms: the host's parts of a frame (Session.host: the streamed nodes' writes, plans "
         f"and evictions; issuing the GPU work, where a driver with a full queue blocks), GPU ms: the frame's GPU time "
         f"from its first timestamp to its last (frames that filled; read after the leg); slow frames: moving frames "
         f"over {SLOW_MS:.1f} ms (the frame target), and the median of each part over them. Resident nodes and points: at the end of the leg; loading max: most nodes in flight in a frame; "
         f"evicted: nodes evicted during the leg and its stop; nodes read: since open (a node evicted and needed again "
         f"is read again). Frames that changed the store (nodes written, for at most {WRITE_SECONDS * 1e3:g} ms "
         f"a frame past the first node while the camera moves, {WRITE_STILL_SECONDS * 1e3:g} ms while it holds still, "
         f"or evicted) took a median {changes}, the others {others}."),
        (f"HTTP: tests/range_server.py's RangeServer on 127.0.0.1 (the file held in memory, answering in threads of "
         f"a process of its own: RangeServerProcess, each answer {latency_s * 1e3:g} ms late), one session for "
         f"each number of range requests in flight (HttpOptions.in_flight, `--http-requests`; 'HTTP n' where the "
         f"run compares several); MB fetched and "
         f"requests: the client's counts (Session.status().copc[0]) at the end of each leg, cumulative; the server "
         f"counted " + ", ".join(f"{r['server_requests']:,} requests and {r['server_bytes'] / 2**20:.1f} MiB "
                                 f"({label})" for label, r in remotes.items()) + " in all."),
        (f"End of the path: {ends}; the file session's nodes took {used} of the store's {batches} batches of {batch_points:,} "
         f"points, their points filling {filled:.0%} of them (a node takes whole batches: the rest is each node's "
         f"last batch's padding); "
         f"failed nodes: " + ", ".join(f"{label} {r['failed_nodes']}" for label, r in runs.items()) + ". "
         + (f"Not converged within {limit_s:.0f} s: {', '.join(unsettled)}. " if unsettled else "")
         + f"Load average (1 min) {load_before:.1f} before, {load_after:.1f} after, on {os.cpu_count()} cores shared "
           f"with other work: other processes show in the frame times and the seconds to settle."),
    ]
    table.notes.insert(1, decode_note(ceiling, local["legs"][0]["resident_points"]))
    table.raw = {"built": {k: str(v) if isinstance(v, Path) else v for k, v in asdict(built).items()},
                 "limit_bytes": limit, "size": list(size), "frames_per_leg": frames, "pixel_bytes": pixel_bytes,
                 "staging_bytes": staging, "corner": CORNER, "close": CLOSE, "fly": FLY, "still_seconds": limit_s,
                 "load_average": [load_before, load_after], "warm_up": warm, "file": local,
                 "http": {str(n): remotes[label] for n, label in zip(requests, remotes)},
                 "http_latency_s": latency_s, "detail_px": detail_px, "decode_ceiling": ceiling}
    return table, RunInfo.from_caps(caps, f"streamed, {limit / 2**20:.0f} MiB limit, {width}x{height}, "
                                          f"detail {detail_px:g} px")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.stream", description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=POINTS)
    ap.add_argument("--limit", type=bytes_arg, default=bytes_arg(LIMIT), help="GPU memory limit, e.g. 64M")
    ap.add_argument("--size", default=SIZE, help="image WxH")
    ap.add_argument("--frames", type=int, default=LEG_FRAMES, help="moving frames per leg of the path")
    ap.add_argument("--still-seconds", type=float, default=STILL_SECONDS, help="longest wait for a still view")
    ap.add_argument("--cache", type=Path, default=CACHE, help="where the COPC file is kept")
    ap.add_argument("--laz", action="store_true", help="tile the sample as LAZ before converting (default LAS)")
    ap.add_argument("--build-only", action="store_true", help="make the COPC file and stop (a device call of its own)")
    ap.add_argument("--scratch", type=Path, help="where the convert's out-of-core scratch goes (default: --cache)")
    ap.add_argument("--http-requests", type=int, nargs="+", default=[REQUESTS_IN_FLIGHT], metavar="N",
                    help="range requests in flight over HTTP; several: one HTTP session each, side by side")
    ap.add_argument("--http-latency", type=float, default=0.0, metavar="MS",
                    help="milliseconds each HTTP answer waits before it starts (a farther server's round trip)")
    ap.add_argument("--detail", type=detail_arg, default=FINEST_PX, metavar="PX",
                    help="SessionOptions.stream_detail_px: the finest detail a view reads (0: until the memory is full)")
    ap.add_argument("--out", type=Path, default=None, help="default: bench/results/<machine>/")
    args = ap.parse_args(argv)
    if args.build_only:
        built = build(args.points, args.cache, args.laz, args.scratch)
        print(f"{built.path}: {built.points:,} points, {built.nodes:,} nodes, {built.levels} levels, "
              f"tiled in {built.tile_seconds:.1f} s, converted in {built.convert_seconds:.1f} s")
        return 0
    width, height = (int(v) for v in args.size.split("x"))
    table, info = run(args.points, args.limit, (width, height), args.frames, args.cache, args.still_seconds,
                      args.laz, args.scratch, tuple(args.http_requests),
                      args.http_latency / 1e3, args.detail)
    table.publish(info, args.out, RESULTS)
    return 0


if __name__ == "__main__":
    sys.exit(main())
