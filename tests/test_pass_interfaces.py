"""Pass interfaces: every program a pass builds finds, at each dispatch, each of its
active storage blocks bound by that same pass call (not left over from another pass),
and a pass binds nothing its programs do not declare; no pass module imports another
except the compositions."""

from __future__ import annotations

import ast
import ctypes
import sys
from dataclasses import dataclass, field
from pathlib import Path

import moderngl
import numpy as np
import pytest

from conftest import SAMPLE
from progressive import shaderlib
from progressive.attributes import default_attribute
from progressive.bindings import Binding
from progressive.budget import BudgetParams
from progressive.camera import auto_camera
from progressive.effects import Effects, EyeDome
from progressive.frame_loop import ProgressiveOptions, ProgressiveRenderer
from progressive.glext import GLFunctions, egl_proc_loader
from progressive.passes.permute import gpu_permute
from progressive.passes.present import PresentPass
from progressive.passes.raster_compute import DEFAULT_TUNING, ComputeTuning
from progressive.permutation import Permutation
from progressive.programs import ComputeProgram
from progressive.renderer import Raster, Renderer

REPO = Path(__file__).resolve().parents[1]
PASSES = REPO / "progressive" / "passes"
STORE = str(REPO / "progressive" / "pointstore.py")
W, H = 64, 48

GL_SHADER_STORAGE_BLOCK = 0x92E6
GL_ACTIVE_RESOURCES = 0x92F5
GL_BUFFER_BINDING = 0x9302

LEAVES = {"progressive.passes.handles"}
class StorageBlocks:
    """Active shader storage blocks of a linked program and their binding points
    (glGetProgramResourceiv: neither moderngl nor ComputeProgram lists them)."""

    def __init__(self):
        loader = egl_proc_loader()
        u, i = ctypes.c_uint, ctypes.c_int
        ip = ctypes.POINTER(i)
        self._interface = ctypes.CFUNCTYPE(None, u, u, u, ip)(loader("glGetProgramInterfaceiv"))
        self._resource = ctypes.CFUNCTYPE(None, u, u, u, i, ctypes.POINTER(u), i, ip, ip)(loader("glGetProgramResourceiv"))
        self._cache: dict[int, frozenset[Binding]] = {}

    def forget(self, glo: int) -> None:
        """A new program may take a released one's name (NVIDIA reuses them at once)."""
        self._cache.pop(glo, None)

    def __call__(self, glo: int) -> frozenset[Binding]:
        if glo not in self._cache:
            count = ctypes.c_int(0)
            self._interface(glo, GL_SHADER_STORAGE_BLOCK, GL_ACTIVE_RESOURCES, ctypes.byref(count))
            prop, value = ctypes.c_uint(GL_BUFFER_BINDING), ctypes.c_int(-1)
            found = set()
            for index in range(count.value):
                self._resource(glo, GL_SHADER_STORAGE_BLOCK, index, 1, ctypes.byref(prop), 1, None, ctypes.byref(value))
                found.add(Binding(value.value))
            self._cache[glo] = frozenset(found)
        return self._cache[glo]


@dataclass
class Call:
    """One call into a pass module from outside the passes (its outermost pass frame)."""

    frame: object
    module: str
    bound: set = field(default_factory=set)           # every binding bound within the call
    own: set = field(default_factory=set)             # those not bound by the point store
    used: set = field(default_factory=set)            # active blocks of the programs it dispatched


class Spy:
    """Records, through the few moderngl and ctypes entry points the passes use, which
    pass call bound which binding and which programs it dispatched."""

    def __init__(self, blocks: StorageBlocks):
        self.blocks = blocks
        self.call: Call | None = None
        self.missing: list[str] = []
        self.stray: list[str] = []
        self.programs: dict[int, tuple[str, object]] = {}      # glo -> (building pass, program)
        self.built: set[tuple[str, str]] = set()
        self.unnamed: list[int] = []          # built in the open call, named once it ends
        self.dispatched: set[tuple[str, str]] = set()

    @staticmethod
    def _pass_frames():
        frames, f = [], sys._getframe(2)
        while f is not None:
            if f.f_code.co_filename.startswith(str(PASSES)):
                frames.append(f)
            f = f.f_back
        return frames

    def _current(self) -> tuple[Call | None, list]:
        frames = self._pass_frames()
        if not frames:
            return None, frames
        outer = frames[-1]
        if self.call is None or self.call.frame is not outer:
            self._close()
            self.call = Call(outer, Path(outer.f_code.co_filename).stem)
        return self.call, frames

    def _close(self) -> None:
        self.built |= {self._key(glo) for glo in self.unnamed}
        self.unnamed = []
        if self.call is not None:
            extra = self.call.own - self.call.used
            if extra:
                self.stray.append(f"{self.call.module}: binds {sorted(b.name for b in extra)} no program of the call reads")
        self.call = None

    def built_program(self, program) -> None:
        self.blocks.forget(program.glo)
        self.programs.pop(program.glo, None)
        frames = self._pass_frames()
        if frames:
            self.programs[program.glo] = (Path(frames[-1].f_code.co_filename).stem, program)
            self.unnamed.append(program.glo)

    def _key(self, glo: int) -> tuple[str, str] | None:
        """(pass, label): moderngl programs are labelled after they are made."""
        if glo not in self.programs:
            return None
        module, program = self.programs[glo]
        return module, str(program.label)

    def bind(self, binding: int) -> None:
        call, _ = self._current()
        if call is None:
            return
        call.bound.add(Binding(binding))
        f, from_store = sys._getframe(1), False
        while f is not None and not from_store:
            from_store = f.f_code.co_filename == STORE
            f = f.f_back
        if not from_store:
            call.own.add(Binding(binding))

    def dispatch(self, glo: int) -> None:
        call, _ = self._current()
        key = self._key(glo)
        if call is None or key is None:
            return
        self.dispatched.add(key)
        required = self.blocks(glo)
        call.used |= required
        lacking = required - call.bound
        if lacking:
            self.missing.append(f"{key}: {sorted(b.name for b in lacking)} not bound by {call.module}")

    def finish(self) -> None:
        self._close()


@pytest.fixture
def spy(gl, monkeypatch):
    s = Spy(StorageBlocks())
    compute, program = shaderlib.compute, moderngl.Context.program

    def built_compute(ctx, name, defines=None, extensions=(), label=None):
        p = compute(ctx, name, defines, extensions, label)
        s.built_program(p)
        return p

    def built_program(self, *args, **kwargs):
        p = program(self, *args, **kwargs)
        s.built_program(p)
        return p

    bind = moderngl.Buffer.bind_to_storage_buffer

    def spied_bind(self, binding=0, offset=0, size=-1):
        s.bind(binding)
        return bind(self, binding, offset, size)

    def wrap(cls, name, glo_of):
        original = getattr(cls, name)

        def spied(self, *args, **kwargs):
            s.dispatch(glo_of(self, *args))
            return original(self, *args, **kwargs)

        monkeypatch.setattr(cls, name, spied)

    monkeypatch.setattr(shaderlib, "compute", built_compute)
    monkeypatch.setattr(moderngl.Context, "program", built_program)
    monkeypatch.setattr(moderngl.Buffer, "bind_to_storage_buffer", spied_bind)
    for cls in (ComputeProgram, moderngl.ComputeShader):
        wrap(cls, "run", lambda self, *a: self.glo)
        wrap(cls, "run_indirect", lambda self, *a: self.glo)
    wrap(moderngl.VertexArray, "render", lambda self, *a: self.program.glo)
    wrap(GLFunctions, "draw_points_indirect", lambda self, program_glo, *a: program_glo)
    return s


def exercise(gl, cloud, raster: Raster, tuning: ComputeTuning = DEFAULT_TUNING) -> None:
    """Brute force with effects, then progressive frames (reference, reprojection,
    effects, an attribute switch, the class filter, a percentile range)."""
    info, batches = cloud
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    effects = Effects(point_size=3, eye_dome=EyeDome())
    r = Renderer(gl, info, default_attribute(info), raster=raster, width=W, height=H, tuning=tuning,
                 class_filter=True)
    for b in batches:
        r.add_batch(b)
    r.render(cam, W, H, r.style(), effects)
    r.render(cam, W, H, r.style(), hidden=frozenset({2}))
    r.release()
    attribute = info.attribute("intensity")
    pr = ProgressiveRenderer(gl, info, default_attribute(info),
                             ProgressiveOptions(W, H, raster=raster, budget=BudgetParams(fixed=30_000),
                                                batches_per_frame=100, reference=True, keep_batches=True,
                                                class_filter=True, tuning=tuning))
    for b in batches:
        pr.add_batch(b)
    style = pr.scene.style()
    for k in range(4):
        pr.frame(cam, style, effects if k % 2 else Effects())
    pr.switch_attribute(attribute)
    for _ in range(200):
        if not pr.switching:
            break
        pr.frame(cam, style)
    style = pr.scene.style()
    for _ in range(3):
        pr.frame(cam, style, effects)
    pr.flush()
    gl.check()
    pr.release()
    streamed(gl, cam, raster, tuning)


def streamed(gl, cam, raster: Raster, tuning: ComputeTuning) -> None:
    """A streamed store whose second half of batches arrives in a still view: those
    batches are drawn whole (ComputeRaster.draw_batches) in the next frame."""
    from progressive.loaders import CloudLoader
    from progressive.permutation import BATCH_POINTS
    from progressive.scene import Scene

    with CloudLoader([SAMPLE], batch_points=BATCH_POINTS) as loader:
        info = loader.info
        loader.start()
        parts = sorted(loader, key=lambda b: b.start)
    scene = Scene(gl, info, default_attribute(info), streamed=True)
    options = ProgressiveOptions(W, H, raster=raster, budget=BudgetParams(fixed=30_000), tuning=tuning)
    pr = ProgressiveRenderer(gl, info, scene.attribute, options, scene=scene)
    half = len(parts) // 2
    for b, part in enumerate(parts):
        scene.write_store_batches(part, b)
        if b + 1 in (half, len(parts)):
            pr.nodes_changed(False, range(half) if b + 1 == half else range(half, len(parts)))
            scene.settled = True
            for _ in range(2):
                pr.frame(cam, scene.style())
    pr.flush()
    gl.check()
    pr.release()
    scene.release()


def test_each_program_finds_its_storage_blocks_bound_by_its_own_pass(gl, sample_batches, spy, monkeypatch):
    for raster in (Raster.COMPUTE, Raster.COMPUTE32, Raster.POINTS):
        exercise(gl, sample_batches, raster)
    exercise(gl, sample_batches, Raster.COMPUTE32, ComputeTuning(batch_groups=False))
    for raster in (Raster.COMPUTE, Raster.COMPUTE32):
        exercise(gl, sample_batches, raster, ComputeTuning(winners=True))
    perm = Permutation.for_count(1000)
    assert np.array_equal(gpu_permute(gl, perm, np.arange(1000), int64=gl.caps.shader_int64),
                          perm.forward(np.arange(1000)))
    shown = gl.ctx.fbo or gl.ctx.detect_framebuffer()      # the framebuffer later tests find bound
    target = gl.ctx.simple_framebuffer((W, H))
    monkeypatch.setattr(moderngl.Context, "screen", property(lambda self: target))
    present = PresentPass(gl)
    image = gl.ctx.buffer(reserve=W * H * 4)
    present.run(image, (W, H), (W, H))
    shown.use()
    gl.ctx.fbo = None
    gl.ctx.finish()
    gl.check()
    for obj in (present, image, target):
        obj.release()
    spy.finish()
    assert spy.missing == [] and spy.stray == []
    undispatched = sorted(set(spy.built) - set(spy.dispatched))
    assert undispatched == [], f"programs built but never dispatched here, so not checked: {undispatched}"
    assert len(spy.built) >= 20         # the scenarios reach every pass's programs


def test_a_program_that_reads_a_block_nobody_bound_is_caught(gl, spy):
    """The check can fail: eye-dome lighting given a visibility buffer whose bind() binds
    nothing reads a block its call did not bind (whatever another pass left there)."""
    from progressive.passes.eye_dome import EyeDomePass

    @dataclass
    class Unbound:
        width: int = W
        height: int = H

        def bind(self) -> None:
            pass

    p = EyeDomePass(gl)
    image = gl.ctx.buffer(reserve=W * H * 4)
    p.run(Unbound(), image, EyeDome())
    gl.ctx.finish()
    spy.finish()
    image.release()
    p.release()
    assert spy.missing == ["('eye_dome', 'eye-dome lighting'): ['VISIBILITY'] not bound by eye_dome"]


def _imports(path: Path, package: str) -> set[str]:
    """Every module a file imports, and each name imported from one as a submodule
    (`from progressive.passes import budget`); relative imports resolved in `package`."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = package.rsplit(".", node.level - 1)[0] if node.level else ""
            module = ".".join(p for p in (base, node.module) if p)
            names.add(module)
            names |= {f"{module}.{a.name}" for a in node.names}
    return names


def pass_imports() -> dict[str, set[str]]:
    """Each pass module and the other pass modules it imports."""
    modules = {f"progressive.passes.{p.stem}" for p in PASSES.glob("*.py") if p.stem != "__init__"}
    return {f"progressive.passes.{p.stem}": (_imports(p, "progressive.passes") & modules) - {f"progressive.passes.{p.stem}"}
            for p in PASSES.glob("*.py")}


def test_no_pass_imports_another_pass_except_the_compositions():
    """Passes meet through handles.py; the compositions that wire them (frame_loop.py,
    renderer.py, shading.py) live outside progressive/passes/."""
    found = pass_imports()
    assert "progressive.passes.handles" in found["progressive.passes.raster_compute"]
    leaks = {m: sorted(i - LEAVES) for m, i in found.items()}
    assert {m: i for m, i in leaks.items() if i} == {}
    assert found["progressive.passes.handles"] == set()


def test_the_import_parser_sees_every_form(tmp_path):
    source = tmp_path / "x.py"
    source.write_text("import progressive.passes.budget\nfrom progressive.passes import cull\n"
                      "from .prepare import Meta\nfrom . import stats\n", encoding="utf-8")
    found = _imports(source, "progressive.passes")
    assert {"progressive.passes.budget", "progressive.passes.cull", "progressive.passes.prepare",
            "progressive.passes.stats"} <= found
