"""From visible points to pixels: resolve, with the effects a frame asks for around
it (point-size dilation before, eye-dome lighting after), each pass made on first use."""

from __future__ import annotations

from progressive.colors import ColorStyle
from progressive.context import GLContext
from progressive.effects import Effects
from progressive.passes.dilate import DilatePass
from progressive.passes.eye_dome import EyeDomePass
from progressive.passes.resolve import ResolvePass
from progressive.passes.visibility import VisibilityBuffer
from progressive.pointstore import PointStore


class Shading:
    def __init__(self, glc: GLContext, store: PointStore, vis: VisibilityBuffer, *, pixel_words: bool = False):
        """pixel_words: visible points' words come per pixel from prepare (progressive)."""
        self.glc, self.vis, self.pixel_words = glc, vis, pixel_words
        self.resolve = ResolvePass(glc, store, vis, pixel_words=pixel_words)
        self.dilate: DilatePass | None = None
        self.dilated: VisibilityBuffer | None = None
        self.eye_dome: EyeDomePass | None = None
        self.shown = vis

    def run(self, style: ColorStyle, effects: Effects, words=None) -> list[str]:
        """The passes that ran. `words`: prepare's per-pixel words, with pixel_words."""
        passes = []
        self.shown = self.vis
        if effects.point_size > 1:
            self._make_dilate()
            self.dilated.resize(self.vis.width, self.vis.height)
            self.dilate.run(self.vis, self.dilated, effects.point_size, words)
            self.shown = self.dilated
            words = self.dilate.words
            passes.append("dilate")
        self.resolve.run(style, words, vis=self.shown)
        passes.append("resolve")
        if effects.eye_dome is not None:
            self.eye_dome = self.eye_dome or EyeDomePass(self.glc)
            self.eye_dome.run(self.shown, self.resolve.image, effects.eye_dome)
            passes.append("eye_dome")
        return passes

    def _make_dilate(self) -> None:
        if self.dilate is None:
            self.dilate = DilatePass(self.glc, pixel_words=self.pixel_words)
            self.dilated = VisibilityBuffer(self.glc, self.vis.width, self.vis.height, label="dilated visibility")

    def cost_ms(self, effects: Effects, words=None, repeats: int = 3) -> dict[str, float]:
        """GPU milliseconds of each effect pass `effects` asks for ("dilate", "eye_dome"),
        timed on the last frame's visibility at its size into scratch buffers, so the
        shown image and buffers stay as they are. Blocks on the GPU: for a probe, not a frame."""
        from progressive.timing import Timestamps

        vis, out = self.vis, {}
        stamps = Timestamps(self.glc, capacity=4)
        scratch = VisibilityBuffer(self.glc, vis.width, vis.height, label="probe visibility")
        image = self.glc.ctx.buffer(reserve=vis.pixels * 4)
        try:
            stamps.stamp("start")
            if effects.point_size > 1:
                self._make_dilate()
                for _ in range(repeats):
                    self.dilate.run(vis, scratch, effects.point_size, words)
                stamps.stamp("dilate")
            if effects.eye_dome is not None:
                self.eye_dome = self.eye_dome or EyeDomePass(self.glc)
                for _ in range(repeats):
                    self.eye_dome.run(vis, image, effects.eye_dome)
                stamps.stamp("eye_dome")
            out = {name: ms / repeats for name, ms in stamps.durations_ms().items()}
        finally:
            for obj in (stamps, scratch, image):
                obj.release()
        return out

    def read(self):
        """(H, W, 4) uint8 RGBA of the last run, row 0 at the top."""
        return self.resolve.read()

    def release(self) -> None:
        for obj in (self.resolve, self.dilate, self.dilated, self.eye_dome):
            if obj is not None:
                obj.release()
