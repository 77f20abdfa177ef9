"""The Dear ImGui panel (imgui-bundle), docked at the window's left with its own
width: files and loading, colouring with its legend (colour bar and histogram, or
the classes), picks, measurements, views, effects, clip, budget and statistics in
collapsible sections; and over the free area the axes gizmo, the scale bar, the fly
mode indicator and notes. It reads the viewer's state and calls the viewer to change
it; what it drew last is kept for the tests, and it owns no other state but imgui's."""

from __future__ import annotations

import json
import time
from collections import deque
from dataclasses import replace
from pathlib import Path

import numpy as np
from imgui_bundle import imgui

from progressive.camera import NO_CLIP, Clip, Returns, project
from progressive.colors import NO_RANGE, Colormap, ColorMode, Palette
from progressive.effects import MAX_POINT_SIZE, EyeDome
from progressive.loaders.types import AttributeKind
from progressive.measure import Measurement
from progressive.viewer import clipbox
from progressive.viewer.controls import KEYS, MOUSE_HELP, VIEW_ACTIONS, Action, BudgetMode
from progressive.viewer.status import copc_lines, stream_lines

ERROR_COLOUR = imgui.ImVec4(1.0, 0.35, 0.3, 1.0)
NOTE_COLOUR = imgui.ImVec4(0.95, 0.8, 0.4, 1.0)
CLIP_COLOUR = imgui.ImVec4(0.3, 0.85, 1.0, 0.9)
HANDLE_COLOUR = imgui.ImVec4(1.0, 1.0, 1.0, 0.95)
COLORMAPS = list(Colormap)
PASSES = ("reproject", "fill", "prepare", "resolve", "frame")
AXIS_COLOURS = {"X": imgui.ImVec4(1.0, 0.3, 0.3, 1.0), "Y": imgui.ImVec4(0.3, 1.0, 0.3, 1.0),
                "Z": imgui.ImVec4(0.35, 0.55, 1.0, 1.0)}
GIZMO_PIXELS = 36.0           # an axis lying in the screen plane is this long (screen units)
OVERLAY_COLOUR = imgui.ImVec4(1.0, 1.0, 1.0, 0.95)
SHADOW_COLOUR = imgui.ImVec4(0.0, 0.0, 0.0, 0.7)
FLY_COLOUR = imgui.ImVec4(1.0, 0.75, 0.2, 1.0)
HISTOGRAM_HEIGHT = 48.0


class Panel:
    def __init__(self, viewer):
        self.viewer = viewer
        import OpenGL

        # Before the backend imports OpenGL.GL: its calls would raise on GL errors left
        # by moderngl's; the tests check ctx.error after every viewer step instead.
        OpenGL.ERROR_CHECKING = False
        from imgui_bundle.python_backends.glfw_backend import GlfwRenderer

        self.context = imgui.create_context()
        imgui.get_io().set_ini_filename("")
        self.renderer = GlfwRenderer(viewer.window, attach_callbacks=False)
        self.frame_times: deque[float] = deque(maxlen=60)
        self.colour_bar: tuple[str, float, float] | None = None   # what the last frame's colour bar showed
        self.clip_overlay: tuple[int, int] = (0, 0)               # edges and handles the last frame drew
        self.histogram: np.ndarray | None = None                  # the counts the last frame's histogram drew
        self.legend: list[tuple[int, str, tuple[int, int, int]]] = []   # the classes it listed
        self.picked_lines: list[str] = []                         # the picked point's lines
        self.effect_lines: tuple[str, str] = ("", "")             # why this point size, why EDL on/off
        self.gizmo: dict[str, tuple[float, float]] = {}           # axis -> screen end (framebuffer pixels)
        self.gizmo_centre: tuple[float, float] = (0.0, 0.0)
        self.scale_bar: tuple[float, float, str] | None = None    # length, pixels, label
        self.notes: list[str] = []                                # notes shown over the free area
        self.fly_shown = False
        self.docked: tuple[float, float] = (0.0, 0.0)             # the panel window's position and width
        self._last = time.perf_counter()

    def wants_mouse(self) -> bool:
        return bool(imgui.get_io().want_capture_mouse)

    def wants_keyboard(self) -> bool:
        return bool(imgui.get_io().want_capture_keyboard)

    def popup_open(self) -> bool:
        """A dropdown, colour picker or other popup of the panel is open (Esc closes it)."""
        imgui.set_current_context(self.context)
        return bool(imgui.is_popup_open("", imgui.PopupFlags_.any_popup))

    def draw(self) -> None:
        self.colour_bar, self.histogram, self.legend, self.picked_lines = None, None, [], []
        now = time.perf_counter()
        self.frame_times.append(now - self._last)
        self._last = now
        imgui.set_current_context(self.context)
        self.renderer.process_inputs()
        imgui.new_frame()
        v = self.viewer
        self._clip_overlay()
        self._overlays()
        if v.settings.panel:
            self._panel()
        if v.error:
            self._error()
        if v.settings.help:
            self._help()
        imgui.render()
        self.renderer.render(imgui.get_draw_data())

    # ---- windows -------------------------------------------------------------------
    def _panel(self) -> None:
        """Docked at the left, the window's height, the viewer's panel width; it scrolls."""
        io = imgui.get_io()
        width = self.viewer.panel_width / io.display_framebuffer_scale.x
        imgui.set_next_window_pos(imgui.ImVec2(0, 0), imgui.Cond_.always)
        imgui.set_next_window_size(imgui.ImVec2(width, io.display_size.y), imgui.Cond_.always)
        flags = imgui.WindowFlags_.no_move | imgui.WindowFlags_.no_resize | imgui.WindowFlags_.no_collapse
        imgui.begin("progressive  (Tab hides, H help)", None, flags)
        pos, size = imgui.get_window_pos(), imgui.get_window_size()
        self.docked = (float(pos.x), float(size.x))
        imgui.push_item_width(min(180.0, width * 0.5))
        s = self.viewer.session
        if s is None:
            imgui.text("no cloud: drop a LAS/LAZ file here")
        else:
            self._files(s)
            self._colouring(s)
            self._classes(s)
            self._picked()
            self._measure()
            self._view()
            self._effects()
            self._clip(s)
            self._budget()
            self._stats(s)
        imgui.pop_item_width()
        imgui.end()

    def _files(self, s) -> None:
        if imgui.collapsing_header("Files", imgui.TreeNodeFlags_.default_open):
            status = s.status()
            for f, copc in zip(s.info.files, status.copc, strict=True):
                imgui.text(f"{Path(f.path).name}: {f.points:,} points ({f.format} {f.version})")
                imgui.text(f"    CRS: {f.crs or 'none given'}")
                for line in copc_lines(copc, streamed=status.stream is not None) if copc is not None else ():
                    imgui.text(line)
            for line in stream_lines(status.stream) if status.stream is not None else ():
                imgui.text(line)
            if status.stream is not None:
                changed, px = imgui.input_float("finest detail px", self.viewer.settings.stream_detail_px, 0.125, 0.5,
                                                "%.3f")
                if changed:
                    self.viewer.set_stream_detail(px)
                imgui.text("    (0: read nodes until the memory is full; more: fewer reads, coarser)")
            loaded, total = status.loaded, status.points
            imgui.progress_bar(loaded / max(1, total), imgui.ImVec2(-1, 0), f"{loaded:,} / {total:,} loaded")

    def _colouring(self, s) -> None:
        v = self.viewer
        if not imgui.collapsing_header("Colour", imgui.TreeNodeFlags_.default_open):
            return
        names = v.attribute_names
        current = names.index(v.settings.attribute) if v.settings.attribute in names else 0
        changed, index = imgui.combo("attribute ([ ])", current, names)
        if changed:
            v.switch_attribute(names[index])
        status = s.status()
        switch, later = status.switch, status.later
        if later is not None:
            imgui.progress_bar(later.read / max(1, status.points), imgui.ImVec2(-1, 0), "reading the other attributes")
            if later.waiting:
                imgui.text(f"showing {later.waiting} once read")
        if switch is not None and not switch.done:
            imgui.progress_bar(switch.streamed / max(1, switch.total), imgui.ImVec2(-1, 0), "streaming")
        elif switch is not None and switch.rate:
            imgui.text(f"switched at {switch.rate / 1e6:.1f} M points/s")
        attribute = s.attribute
        if attribute.kind is AttributeKind.SCALAR:
            changed, index = imgui.combo("colormap", COLORMAPS.index(v.settings.colormap),
                                         [c.name.lower() for c in COLORMAPS])
            if changed:
                v.set_colormap(COLORMAPS[index])
            lo, hi = s.color_range(v.settings.value_range) or NO_RANGE
            speed = max(abs(hi - lo), 1e-6) / 200.0
            changed, values = imgui.drag_float2("range", [lo, hi], speed)
            if changed:
                v.settings = replace(v.settings, value_range=(values[0], values[1]))
            imgui.same_line()
            if imgui.small_button("auto"):
                v.settings = replace(v.settings, value_range=None)
            self._colour_bar(s, attribute.name, lo, hi)
        elif ColorMode.for_kind(attribute.kind) is ColorMode.CATEGORY:
            self._legend(s.options.palette)
        changed, colour = imgui.color_edit3("background", [c / 255.0 for c in v.settings.background])
        if changed:
            v.settings = replace(v.settings, background=tuple(int(round(c * 255)) for c in colour))

    def _colour_bar(self, s, name: str, lo: float, hi: float) -> None:
        """The colormap as a bar from the range's low end to its high end, labelled with
        the values (the attribute's units: the file's for elevation), and under it the
        histogram of the loaded values over the range, each bar in its colour."""
        palette = s.style(self.viewer.settings.colormap).palette
        draw = imgui.get_window_draw_list()
        start = imgui.get_cursor_screen_pos()
        width, height, steps = imgui.get_content_region_avail().x, 14.0, 64
        colour_at = lambda t: imgui.get_color_u32(_word_colour(palette[round(t * 255)]))  # noqa: E731
        for k in range(steps):
            x0 = start.x + width * k / steps
            draw.add_rect_filled(imgui.ImVec2(x0, start.y), imgui.ImVec2(x0 + width / steps + 1, start.y + height),
                                 colour_at(k / (steps - 1)))
        imgui.dummy(imgui.ImVec2(width, height))
        units = f" ({s.units})" if name == "elevation" and s.units else ""
        imgui.text(f"{lo:.6g}")
        label = f"{hi:.6g}"
        imgui.same_line(width - imgui.calc_text_size(label).x)
        imgui.text(label)
        imgui.text_disabled(f"{name}{units}, 1-99 % of the loaded points" if self.viewer.settings.value_range is None
                            else f"{name}{units}, range set")
        self.colour_bar = (name, lo, hi)
        shown = self.viewer.histogram()
        if shown is None:
            return
        counts, _ = shown
        top = imgui.get_cursor_screen_pos()
        tallest = max(int(counts.max()), 1)
        bins = len(counts)
        for k, c in enumerate(counts):
            x0 = top.x + width * k / bins
            y0 = top.y + HISTOGRAM_HEIGHT * (1.0 - c / tallest)
            draw.add_rect_filled(imgui.ImVec2(x0, y0), imgui.ImVec2(x0 + max(width / bins - 1, 1), top.y + HISTOGRAM_HEIGHT),
                                 colour_at(k / max(bins - 1, 1)))
        imgui.dummy(imgui.ImVec2(width, HISTOGRAM_HEIGHT))
        imgui.text_disabled(f"histogram of {int(counts.sum()):,} points in range")
        self.histogram = counts

    def _legend(self, palette: Palette) -> None:
        """The classes present, each with its ASPRS name, its colour in the session's
        palette (--palette overrides included) and a visibility toggle."""
        v = self.viewer
        for code in v.categories():
            name, rgb = palette.name(code), palette.rgb(code)
            self.legend.append((code, name, rgb))
            imgui.color_button(f"##class{code}", imgui.ImVec4(*(c / 255.0 for c in rgb), 1.0),
                               0, imgui.ImVec2(12, 12))
            imgui.same_line()
            changed, _ = imgui.checkbox(f"{code:3d} {name}", code not in v.settings.hidden_classes)
            if changed:
                v.toggle_class(code)

    def _effects(self) -> None:
        v = self.viewer
        if not imgui.collapsing_header("Points and lighting", imgui.TreeNodeFlags_.default_open):
            return
        changed, size = imgui.slider_int("point size (+ -)", v.settings.point_size, 1, MAX_POINT_SIZE)
        if changed:
            v.settings = replace(v.settings, point_size=size)
        self.effect_lines = effect_lines(v)
        imgui.text_wrapped(self.effect_lines[0])
        changed, on = imgui.checkbox("eye-dome lighting (E)", v.settings.eye_dome)
        if changed:
            v.settings = replace(v.settings, eye_dome=on)
        imgui.text_wrapped(self.effect_lines[1])
        if not (v.auto_point_size and v.auto_eye_dome) and imgui.button("automatic point size and lighting"):
            v.automatic_effects()
        if v.settings.eye_dome:
            p = v.settings.eye_dome_params
            c1, strength = imgui.slider_float("strength", p.strength, 0.0, 5.0)
            c2, radius = imgui.slider_float("radius", p.radius, 0.5, 8.0)
            if c1 or c2:
                v.settings = replace(v.settings, eye_dome_params=EyeDome(strength, radius))

    def _classes(self, s) -> None:
        """Return filters and, while another attribute is shown, class toggles (the GPU
        keeps every point's class and return flags); colouring by classification shows
        the toggles in its legend."""
        v = self.viewer
        if not s.filters_classes or not imgui.collapsing_header("Classes and returns"):
            return
        for i, returns in enumerate(Returns):
            if i:
                imgui.same_line()
            if imgui.radio_button(f"{returns.name.lower()} returns", v.settings.returns is returns):
                v.settings = replace(v.settings, returns=returns)
        if ColorMode.for_kind(s.attribute.kind) is not ColorMode.CATEGORY:
            self._legend(s.options.palette)

    def _picked(self) -> None:
        """The last clicked point: a marker where it was found and all of it, as read
        back from its file (x, y, z with the digits the file's scale carries)."""
        p = self.viewer.picked
        if p is None or not imgui.collapsing_header("Picked point", imgui.TreeNodeFlags_.default_open):
            return
        col, row = p["pixel"]
        scale = imgui.get_io().display_framebuffer_scale
        imgui.get_foreground_draw_list().add_circle(imgui.ImVec2(col / scale.x, row / scale.y), 6.0,
                                                    imgui.get_color_u32(imgui.ImVec4(1, 0.2, 0.2, 1)), 0, 2.0)
        self.picked_lines = picked_lines(p)
        for line in self.picked_lines:
            imgui.text(line)
        if imgui.small_button("copy as JSON"):
            imgui.set_clipboard_text(json.dumps(p))
            self.viewer.say("picked point copied as JSON")

    def _measure(self) -> None:
        """Shift+clicked points: a line through them in the window with each segment's
        length, and in the panel the 3D, horizontal and vertical lengths, the running
        length and the enclosed area (file units)."""
        v = self.viewer
        m = v.measurement
        if not m.points or not imgui.collapsing_header("Measure", imgui.TreeNodeFlags_.default_open):
            return
        width, height = v.framebuffer_size
        pixel, _ = project(v.camera, np.asarray(m.points), width, height)
        scale = imgui.get_io().display_framebuffer_scale
        screen = [imgui.ImVec2((p % width + 0.5) / scale.x, (p // width + 0.5) / scale.y) if p >= 0 else None
                  for p in pixel]
        draw = imgui.get_foreground_draw_list()
        colour = imgui.get_color_u32(imgui.ImVec4(1.0, 0.9, 0.2, 1.0))
        segments = m.segments()
        for i, seg in enumerate(segments):
            a, b = screen[i], screen[i + 1]
            if a is not None and b is not None:
                draw.add_line(a, b, colour, 2.0)
                draw.add_text(imgui.ImVec2((a.x + b.x) / 2, (a.y + b.y) / 2), colour, f"{seg['distance']:.3f}")
            imgui.text(f"{i + 1}: {seg['distance']:.3f}  (horizontal {seg['horizontal']:.3f}, "
                       f"vertical {seg['vertical']:.3f})")
        imgui.text(f"{len(m.points)} points, length {m.length:.3f}, area {m.area:.3f}")
        if imgui.small_button("copy measurement as JSON"):
            imgui.set_clipboard_text(json.dumps(m.to_dict()))
            v.say("measurement copied as JSON")
        imgui.same_line()
        if imgui.small_button("clear"):
            v.measurement = Measurement(())

    def _view(self) -> None:
        """Standard views (keys 1-4) and the projection (O)."""
        v = self.viewer
        if v.navigator is None or not imgui.collapsing_header("View", imgui.TreeNodeFlags_.default_open):
            return
        for i, action in enumerate(VIEW_ACTIONS):
            if i:
                imgui.same_line()
            if imgui.small_button(VIEW_ACTIONS[action].value):
                v.act(action)
        changed, _ = imgui.checkbox("orthographic (O)", v.orbit.orthographic)
        if changed:
            v.act(Action.PROJECTION)

    def _clip(self, s) -> None:
        """A clip box edited with numbers in the file's coordinates (float64 fields: a
        UTM northing keeps its millimetres), starting from the cloud's bounds, or by
        dragging its faces' handles in the window; and a section along the last two
        measured points, with its width."""
        v = self.viewer
        if not imgui.collapsing_header("Clip"):
            return
        clip = v.settings.clip
        changed, on = imgui.checkbox("clip box (drag its handles in the window)", clip.has_box)
        if changed:
            box = (tuple(s.info.bounds_min), tuple(s.info.bounds_max)) if on else (NO_CLIP.lo, NO_CLIP.hi)
            v.settings = replace(v.settings, clip=Clip(*box, clip.section))
        clip = v.settings.clip
        if clip.has_box:
            lo, hi = list(clip.lo), list(clip.hi)
            edited = False
            for label, corner in (("min", lo), ("max", hi)):
                for axis, name in enumerate("xyz"):
                    if np.isfinite(corner[axis]):
                        changed, corner[axis] = imgui.input_double(f"{label} {name}", corner[axis], 0.0, 0.0, "%.3f")
                        edited |= changed
            if edited and all(a <= b for a, b in zip(lo, hi)):
                v.settings = replace(v.settings, clip=Clip(tuple(lo), tuple(hi), clip.section))
        changed, width = imgui.input_double("section width", v.section_width, 0.0, 0.0, "%.3f")
        if changed and width > 0:
            v.set_section_width(width)
        imgui.begin_disabled(len(v.measurement.points) < 2)
        if imgui.small_button("Section along line"):
            v.section_along_line()
        imgui.end_disabled()
        section = v.settings.clip.section
        if section is None:
            imgui.text_disabled("(Shift+click two points first)" if len(v.measurement.points) < 2 else "")
            return
        imgui.same_line()
        if imgui.small_button("profile view"):
            v.profile_view()
        imgui.same_line()
        if imgui.small_button("clear section"):
            v.clear_section()
        imgui.text(f"from {section.start[0]:.3f}, {section.start[1]:.3f} to {section.end[0]:.3f}, "
                   f"{section.end[1]:.3f}: length {section.length:.3f}")

    def _clip_overlay(self) -> None:
        """The clip box's edges over the image and a handle at each face's centre (the
        one dragged, or under the cursor, larger)."""
        v = self.viewer
        box = v.shown_clip_box()
        if box is None or v.navigator is None:
            self.clip_overlay = (0, 0)
            return
        camera, size = v.camera, v.framebuffer_size
        scale = imgui.get_io().display_framebuffer_scale
        at = lambda xy: imgui.ImVec2(float(xy[0]) / scale.x, float(xy[1]) / scale.y)  # noqa: E731
        draw = imgui.get_background_draw_list()
        colour, handle = imgui.get_color_u32(CLIP_COLOUR), imgui.get_color_u32(HANDLE_COLOUR)
        edges = clipbox.box_edges(camera, *box, size)
        for a, b in edges:
            draw.add_line(at(a), at(b), colour, 1.5)
        mouse = imgui.get_io().mouse_pos
        hover = clipbox.handle_at(camera, *box, size, mouse.x * scale.x, mouse.y * scale.y)
        handles = clipbox.face_handles(camera, *box, size)
        for face, xy in handles.items():
            big = face == v.dragged_face() or face == hover
            draw.add_circle_filled(at(xy), 6.0 if big else 4.0, colour if big else handle)
        self.clip_overlay = (len(edges), len(handles))

    def _budget(self) -> None:
        v = self.viewer
        if not imgui.collapsing_header("Budget"):
            return
        s = v.settings
        if imgui.radio_button("adaptive", s.budget_mode is BudgetMode.ADAPTIVE):
            v.set_budget(BudgetMode.ADAPTIVE)
        imgui.same_line()
        if imgui.radio_button("fixed", s.budget_mode is BudgetMode.FIXED):
            v.set_budget(BudgetMode.FIXED)
        if s.budget_mode is BudgetMode.ADAPTIVE:
            changed, fps = imgui.slider_float("target fps", s.target_fps, 10.0, 240.0)
            if changed:
                v.set_budget(BudgetMode.ADAPTIVE, target_fps=fps)
        else:
            changed, points = imgui.input_int("points a frame", s.fixed_budget, 100_000, 1_000_000)
            if changed and points > 0:
                v.set_budget(BudgetMode.FIXED, fixed=points)

    def _stats(self, s) -> None:
        if not imgui.collapsing_header("Statistics"):
            return
        mean = float(np.mean(self.frame_times)) if self.frame_times else 0.0
        imgui.text(f"{1.0 / mean if mean > 0 else 0.0:.0f} fps ({mean * 1e3:.1f} ms a frame on the CPU)")
        history = s.history
        measured = next((h for h in reversed(history) if h.gpu_ms), None)
        if measured is not None:
            imgui.text("GPU ms: " + "  ".join(f"{k} {measured.gpu_ms[k]:.2f}" for k in PASSES))
            imgui.text("(resolve includes point size and eye-dome lighting; the budget reserves it)")
            imgui.text(f"budget {measured.budget:,} points; {measured.covered_pixels:,} pixels covered")
            kept = 1.0 - measured.gathered / measured.covered_pixels if measured.covered_pixels else 0.0
            imgui.text(f"{kept:.1%} of pixels kept their point from the frame before")
            share = min(1.0, measured.filled_since_change / max(1, s.status().slots))
            label = "exact (every point filled since the last change)" if s.converged else "points filled since the last change"
            imgui.progress_bar(share, imgui.ImVec2(-1, 0), label)
        imgui.text("last frame: " + (" ".join(self.viewer.last_passes) or "idle"))

    def _overlays(self) -> None:
        """Over the free area: notes at its top (saves, copies, pastes, warnings; shown
        with the panel hidden too), the fly mode indicator, the axes gizmo at its bottom
        right and the scale bar at its bottom left."""
        v = self.viewer
        scale = imgui.get_io().display_framebuffer_scale
        x0, y0, x1, y1 = (c / s for c, s in zip(v.free_area, (scale.x, scale.y, scale.x, scale.y)))
        draw = imgui.get_foreground_draw_list()
        line = imgui.get_text_line_height_with_spacing()
        v.expire_messages()
        self.notes = v.messages[-6:]
        y = y0 + 8.0
        self.fly_shown = v.settings.fly
        if v.settings.fly:
            _text(draw, imgui.ImVec2(x0 + 10.0, y), FLY_COLOUR, "FLY MODE (F leaves): W A S D move, Space/Z up/down, "
                                                               "drag to look")
            y += line
        for note in self.notes:
            _text(draw, imgui.ImVec2(x0 + 10.0, y), NOTE_COLOUR, note)
            y += line
        if v.navigator is None:
            self.gizmo, self.scale_bar = {}, None
            return
        centre = imgui.ImVec2(x1 - GIZMO_PIXELS - 18.0, y1 - GIZMO_PIXELS - 18.0)
        axes = v.axes_gizmo()
        self.gizmo, self.gizmo_centre = {}, (centre.x * scale.x, centre.y * scale.y)
        draw.add_circle_filled(centre, GIZMO_PIXELS + 12.0, imgui.get_color_u32(imgui.ImVec4(0, 0, 0, 0.35)))
        for name in sorted(axes, key=lambda a: -abs(axes[a][0]) - abs(axes[a][1])):
            dx, dy = axes[name]
            end = imgui.ImVec2(centre.x + dx * GIZMO_PIXELS, centre.y + dy * GIZMO_PIXELS)
            colour = imgui.get_color_u32(AXIS_COLOURS[name])
            draw.add_line(centre, end, colour, 2.5)
            draw.add_text(imgui.ImVec2(end.x - 4.0, end.y - 7.0), colour, name)
            self.gizmo[name] = (end.x * scale.x, end.y * scale.y)
        bar = v.scale_bar()
        self.scale_bar = bar
        if bar is not None:
            _, pixels, label = bar
            left, base = x0 + 16.0, y1 - 18.0
            right = left + pixels / scale.x
            white = imgui.get_color_u32(OVERLAY_COLOUR)
            shadow = imgui.get_color_u32(SHADOW_COLOUR)
            draw.add_rect_filled(imgui.ImVec2(left - 1, base - 4), imgui.ImVec2(right + 1, base + 2), shadow)
            draw.add_line(imgui.ImVec2(left, base), imgui.ImVec2(right, base), white, 2.0)
            for x in (left, right):
                draw.add_line(imgui.ImVec2(x, base - 6.0), imgui.ImVec2(x, base + 1.0), white, 2.0)
            _text(draw, imgui.ImVec2(left, base - 8.0 - line), OVERLAY_COLOUR, label)

    def _error(self) -> None:
        v = self.viewer
        io = imgui.get_io()
        imgui.set_next_window_pos(imgui.ImVec2(io.display_size.x / 2, io.display_size.y / 2),
                                  imgui.Cond_.always, imgui.ImVec2(0.5, 0.5))
        imgui.begin("Error", None, imgui.WindowFlags_.always_auto_resize | imgui.WindowFlags_.no_collapse)
        imgui.push_text_wrap_pos(480)
        imgui.text_colored(ERROR_COLOUR, v.error)
        imgui.pop_text_wrap_pos()
        if imgui.button("OK"):
            v.error = None
        imgui.end()

    def _help(self) -> None:
        imgui.begin("Help (H)", None, imgui.WindowFlags_.always_auto_resize)
        for label, what in MOUSE_HELP:
            imgui.text(f"{label:32s} {what}")
        imgui.separator()
        for key, action in KEYS.items():
            imgui.text(f"{key:32s} {action.value}")
        imgui.end()

    def release(self) -> None:
        imgui.set_current_context(self.context)
        self.renderer.shutdown()
        imgui.destroy_context(self.context)


def effect_lines(viewer) -> tuple[str, str]:
    """Why the point size and eye-dome lighting are what they are: the rule's reason
    (viewer/defaults.py) while it chooses, else the user's choice beside it."""
    v = viewer.settings
    lines = []
    for auto, choice, what, value in (
            (viewer.auto_point_size, viewer.point_size_choice, "point size", str(v.point_size)),
            (viewer.auto_eye_dome, viewer.eye_dome_choice, "eye-dome lighting", "on" if v.eye_dome else "off")):
        if auto:
            lines.append(choice.reason if choice is not None else f"{what} {value}: chosen once the view converges")
        else:
            rule = f"; the default rule says: {choice.reason}" if choice is not None else ""
            lines.append(f"{what} {value}: your choice{rule}")
    return lines[0], lines[1]


def _word_colour(word: int) -> imgui.ImVec4:
    """An RGBA8 palette word as imgui's colour."""
    return imgui.ImVec4((word & 0xFF) / 255, (word >> 8 & 0xFF) / 255, (word >> 16 & 0xFF) / 255, 1.0)


def _text(draw, at: imgui.ImVec2, colour: imgui.ImVec4, text: str) -> None:
    """Text over the image, with a dark shadow so it reads on any colour."""
    draw.add_text(imgui.ImVec2(at.x + 1, at.y + 1), imgui.get_color_u32(SHADOW_COLOUR), text)
    draw.add_text(at, imgui.get_color_u32(colour), text)


def picked_lines(p: dict) -> list[str]:
    """A pick's record as the panel lists it: file and index, the coordinates in the
    cloud's CRS, latitude and longitude, the file's own coordinates when reprojected,
    and every attribute."""
    lines = [f"{Path(p['file']).name}  point {p['index']:,}", f"x {p['x']}  y {p['y']}  z {p['z']}",
             f"CRS: {p.get('crs') or 'none given'}"]
    if p.get("lat") is not None and p.get("lon") is not None:
        lines.append(f"lat {p['lat']:.8f}  lon {p['lon']:.8f}")
    else:
        lines.append("lat/lon: none (the CRS places nothing on Earth)" if p.get("crs") else "lat/lon: no CRS")
    own = p.get("file_coordinates")
    if own is not None:
        lines.append(f"in the file: x {own['x']}  y {own['y']}  z {own['z']}  ({own['crs'] or 'no CRS'})")
    lines += [f"{name}: {value}" for name, value in p["attributes"].items()]
    return lines
