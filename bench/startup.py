"""Startup: where the time to the first image goes for `progressive render` and
`progressive view` (headless), each run a fresh process, under four cache states:
no caches (Mesa's shader cache off, which also leaves the driver without program
binary formats), a first run (both caches empty, filled by the run), Mesa's cache
warm, and Mesa's cache with the program binary cache warm.

    python -m bench.startup [--repeats 3] [--width 1280 --height 720]
    python -m bench.startup --scaled 100000000 --commands view --caches "Mesa + program cache"

writes bench/results/<machine>/startup.{md,json}; with --scaled N, the sample tiled to N
points as LAS, LAZ and fast format (bench/data.py) instead, to startup_N: what of the
time to the first image grows with the cloud."""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "progressive" / "data" / "autzen_trim.las"
LAZ = REPO.parent / "shared" / "data" / "wires.laz"
PHASES = ("import", "read", "context", "passes", "programs", "upload", "first_frame", "finish")
CACHE_STATES = ("no caches", "first run", "Mesa cache", "Mesa + program cache")


FIRST_IMAGE_LIMIT_S = 60.0
"""The longest a benchmark's session may frame before its first image (else an error, not a hang)."""


def frame_until_first_image(s, camera, what: str, limit_s: float = FIRST_IMAGE_LIMIT_S) -> None:
    """Session `s` framed with `camera` until a frame has shown points: progressive
    frames come before the first batch is parsed (or the first node has arrived)."""
    deadline = time.perf_counter() + limit_s
    while s.first_image_seconds is None:
        if time.perf_counter() > deadline:
            raise RuntimeError(f"{what}: no image within {limit_s:g} s")
        s.frame(camera)


def child(command: str, path: str, width: int, height: int) -> dict:
    """One run as the command would make it, to glFinish after the first image (this
module imports nothing of progressive before, so `import` is what the CLI pays)."""
    t0 = time.perf_counter()
    from progressive import cli
    from progressive.session import Session, SessionOptions

    imported = time.perf_counter()
    if command == "render":
        args = cli.build_parser().parse_args(["render", path, "--out", "unused.png", "--width", str(width),
                                              "--height", str(height)])
        options = cli.session_options(args)
    else:       # as cli._view_headless builds it
        options = SessionOptions(width=width, height=height)
    with Session([path], options) as s:
        frame_until_first_image(s, s.auto_camera(), path)
        returned = time.perf_counter()
        s.glc.ctx.finish()
        done = time.perf_counter()
        out = {"import": imported - t0, **s.startup, "finish": done - returned, "in_process": done - t0,
               "epoch_done": time.time(), "device": s.glc.caps.as_dict(), **s.glc.programs.stats.as_dict()}
    return out


def environment(state: str, warm: dict[str, str]) -> dict[str, str]:
    env = dict(os.environ)
    env.pop("MESA_SHADER_CACHE_DISABLE", None)
    if state == "no caches":
        env.update(MESA_SHADER_CACHE_DISABLE="true", PROGRESSIVE_PROGRAM_CACHE="0")
    elif state == "first run":
        env.update(MESA_SHADER_CACHE_DIR=tempfile.mkdtemp(prefix="mesa-"),
                   PROGRESSIVE_PROGRAM_CACHE=tempfile.mkdtemp(prefix="programs-"))
    elif state == "Mesa cache":
        env.update(MESA_SHADER_CACHE_DIR=warm["mesa"], PROGRESSIVE_PROGRAM_CACHE="0")
    else:
        env.update(MESA_SHADER_CACHE_DIR=warm["mesa"], PROGRESSIVE_PROGRAM_CACHE=warm["programs"])
    return env


def spawn(module: str, kind: str, path: Path, size: tuple[int, int], env: dict[str, str]) -> dict:
    """`python -m MODULE --child KIND PATH W H` in a fresh process: its JSON line, with
    `process` the seconds from spawning it to the child's `epoch_done`."""
    started = time.time()
    done = subprocess.run([sys.executable, "-m", module, "--child", kind, str(path), str(size[0]), str(size[1])],
                          env=env, cwd=REPO, capture_output=True, text=True, check=True)
    result = json.loads(done.stdout.strip().splitlines()[-1])
    result["process"] = result.pop("epoch_done") - started
    return result


def child_arguments(parser: argparse.ArgumentParser, kind: str) -> None:
    """The hidden `--child KIND FILE W H` that spawn passes, and the size options."""
    parser.add_argument("--child", nargs=4, metavar=(kind, "FILE", "W", "H"), help=argparse.SUPPRESS)
    parser.add_argument("--width", type=int, default=1280)
    parser.add_argument("--height", type=int, default=720)
    parser.add_argument("--out", type=Path, default=None, help="results folder (default bench/results/<machine>)")


def answer_child(args: argparse.Namespace, child) -> bool:
    """In a process spawn started: run `child(kind, path, width, height)` and print its
    JSON line for the parent; False in the parent."""
    if not args.child:
        return False
    kind, path, w, h = args.child
    print(json.dumps(child(kind, path, int(w), int(h))))
    return True


def compile_package() -> None:
    """The package's modules as bytecode, as an installed package has them: with
    PYTHONDONTWRITEBYTECODE (set on this project's machines) the children of an
    editable install would each compile every module they import (scripts/setup.sh
    compiles them too)."""
    import compileall

    for folder in ("progressive", "loaders"):
        compileall.compile_dir(str(REPO / folder), quiet=1)


def one(command: str, path: Path, size: tuple[int, int], env: dict[str, str]) -> dict:
    return spawn("bench.startup", command, path, size, env)


def run(files: list[Path], size: tuple[int, int], repeats: int, commands=("render", "view"), states=CACHE_STATES,
        name: str = "startup", points: str = "the files as they are"):
    from bench.report import Table

    table = Table(name, "Time to first image: the phases, per command and cache state", ", ".join(p.name for p in files),
                  points, ("command", "file", "caches", "process s", "import", "read", "context",
                                            "passes", "of which programs", "upload", "first frame", "glFinish",
                                            "programs loaded / compiled"))
    compile_package()
    warm = {"mesa": tempfile.mkdtemp(prefix="mesa-warm-"), "programs": tempfile.mkdtemp(prefix="programs-warm-")}
    rows, device = [], None
    for command in commands:
        for path in files:
            one(command, path, size, environment("Mesa + program cache", warm))      # fills the warm caches
            for state in states:
                runs = [one(command, path, size, environment(state, warm)) for _ in range(repeats)]
                device = runs[0]["device"]
                med = {k: statistics.median(r[k] for r in runs) for k in (*PHASES, "process", "in_process")}
                row = {"command": command, "file": path.name, "caches": state, "runs": runs, "median": med,
                       "hits": runs[-1]["hits"], "misses": runs[-1]["misses"]}
                rows.append(row)
                table.rows.append((command, path.name, state, med["process"], *(med[k] for k in PHASES),
                                   f"{row['hits']} / {row['misses']}"))
    table.notes = [
        (f"Each run a fresh `python` process at {size[0]}x{size[1]}, median of {repeats}; `process s`: from spawning "
         "it to `glFinish` after the first frame with points, the package's modules compiled to bytecode first (as an "
         "install has them). Phases (seconds): import of `progressive.cli` and the session; read: headers and the "
         "files' probes (the default colouring is chosen from them); context: EGL context, "
         "capabilities, GL entry points; passes: buffers and programs of the renderer (programs: compiled, or loaded "
         "from the binary cache); upload: packing and distributing the batches of the first frame; first frame: "
         "issuing the frame that showed points first (the first ones may come before a batch is parsed), upload "
         "included; glFinish: waiting for it (on llvmpipe, the shaders' JIT compile happens here "
         "at their first dispatch unless Mesa's cache holds them)."),
        ("Caches: Mesa's on-disk shader cache (`MESA_SHADER_CACHE_DIR`; `MESA_SHADER_CACHE_DISABLE=true` turns it "
         "off, and with it the driver reports no program binary formats, so the program cache is inactive too) and "
         "progressive's program binary cache (`PROGRESSIVE_PROGRAM_CACHE`). First run: both empty."),
    ]
    table.raw = {"rows": rows, "size": list(size), "repeats": repeats}
    return table, device


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    child_arguments(parser, "COMMAND")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--scaled", type=int, help="the sample tiled to this many points, as LAS, LAZ and fast format")
    parser.add_argument("--laz-only", action="store_true", help="with --scaled: the LAZ alone (1 B points as LAS and "
                                                                 "fast format would not fit the GPU machine's disk)")
    parser.add_argument("--commands", nargs="+", choices=("render", "view"), default=["render", "view"])
    parser.add_argument("--caches", nargs="+", choices=CACHE_STATES, default=list(CACHE_STATES))
    args = parser.parse_args(argv)
    if answer_child(args, child):
        return 0
    extra = {}
    if args.scaled:
        from bench import data
        if args.laz_only:
            files = [data.tiled(args.scaled, compress=True)]
        else:
            made = data.scaled(args.scaled)
            files = [made.las, made.laz, made.fast]
        extra = {"name": f"startup_{args.scaled}", "points": f"{args.scaled:,}"}
    else:
        files = [SAMPLE] + ([LAZ] if LAZ.is_file() else [])
    table, device = run(files, (args.width, args.height), args.repeats, tuple(args.commands), tuple(args.caches),
                        **extra)
    from bench.report import RunInfo
    from progressive.context import Capabilities

    table.publish(RunInfo.from_caps(Capabilities(**device), "startup"), args.out, RESULTS)
    return 0


if __name__ == "__main__":
    sys.exit(main())
