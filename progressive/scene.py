"""A cloud on the GPU: the shuffled store, the distribute pass that fills it, and the
attribute shown (with the exact percentile range it is coloured over). With `keep_batches`
the loaded struct-of-arrays stays in host memory, so the shown attribute can be
switched by streaming one word a point (paper 3.5) instead of reloading the file."""

from __future__ import annotations

import bisect
import time
from dataclasses import dataclass, replace

import numpy as np

from progressive import batches as batch_boxes
from progressive import encoding
from progressive.camera import Returns
from progressive.colors import DEFAULT_PALETTE, NO_RANGE, Colormap, ColorMode, ColorStyle, Palette
from progressive.context import GLContext
from progressive.errors import ProgressiveError
from progressive.loaders.records import ELEVATION, EXPONENT, attribute_word
from progressive.loaders.types import AttributeInfo, AttributeKind, Batch, CloudInfo, nonfinite_records
from progressive.packing import batch_words, pack_into
from progressive.passes.distribute import DistributePass
from progressive.passes.percentile import PercentilePass
from progressive.permutation import BATCH_POINTS, LAYOUT, FillOrder
from progressive.pointstore import PointStore, RecordOrder
from progressive.stagecopy import StageCopier
from progressive.wordpack import PACK_THREADS, WordPacker, WordRun, threaded

RANGE_GROWTH = 2
"""While loading, the colour range is taken anew each time the loaded points have
grown this many times over (and once loading is complete): O(log n) selects."""


@dataclass
class AttributeSwitch:
    """Progress of one switch: the kept batches order[:next_batch] (and the first
    next_row rows of the next) carry the new attribute on the GPU; they are streamed in
    file order, so consecutive batches go as one run of words. `records` counts batches
    that needed whole records because a non-finite value hides (or stops hiding) their
    points; `unchanged` the points whose words held the new attribute already."""

    attribute: AttributeInfo
    previous: tuple[AttributeInfo, ...]   # what the GPU words may still hold
    batches: int                # kept when the switch began; later ones arrive packed with it
    total: int
    order: list[int]            # the kept batches by file index
    next_batch: int = 0
    next_row: int = 0
    streamed: int = 0
    records: int = 0
    unchanged: int = 0
    seconds: float = 0.0

    @property
    def done(self) -> bool:
        return self.next_batch >= self.batches

    @property
    def rate(self) -> float:
        """Points rewritten a second, CPU packing and upload included (the GPU scatter is
        queued)."""
        return (self.streamed - self.unchanged) / self.seconds if self.seconds > 0 else 0.0


class Scene:
    def __init__(self, glc: GLContext, info: CloudInfo, attribute: AttributeInfo, *, chunk_points: int | None = None,
                 capacity: int | None = None, keep_batches: bool = False, order: FillOrder = LAYOUT,
                 class_filter: bool = False, records: RecordOrder = RecordOrder.BATCHES,
                 position_encoding: encoding.Encoding = encoding.Encoding.WORDS,
                 batch_order: batch_boxes.BatchOrder = batch_boxes.BATCH_ORDER, streamed: bool = False):
        """capacity: points kept on the GPU (default all; see progressive/memory.py).
        keep_batches: keep the loaded attributes in host memory to switch attributes.
        order: FILE stores points in file order (the unshuffled baseline, for benchmarks).
        class_filter: keep every point's class and return flags on the GPU, so hidden classes
        and return filters apply whatever attribute is shown (the cloud must have
        classification). records: where the batched layout's records live (the slot
        order is the benchmarks' baseline). position_encoding: how the batched layout
        keeps positions (progressive/encoding.py; float records are the baseline).
        batch_order: batches of consecutive points in file order, or (MORTON, the batched
        layout) each loaded batch's whole store batches sorted by Morton code first.
        streamed: the store's batches are written and emptied one by one
        (write_store_batches, clear_store_batches: progressive/streaming.py), not loaded
        in order; `info.points` is then what its batches hold."""
        self.glc, self.info, self.attribute = glc, info, attribute
        if streamed and (keep_batches or capacity is not None or order is not FillOrder.BATCHED):
            raise ProgressiveError("a streamed cloud keeps whole batches of the batched layout, no attributes on the host")
        self.streamed = streamed
        self.settled = False
        """Streamed: nothing more to read or write for the view (set by the Streamer)."""
        self.writes = 0             # streamed: store batches written or emptied so far
        self._written: dict[int, tuple[int, int]] = {}      # streamed: (points, never drawn) of each written batch
        self._codes = np.zeros(256, dtype=bool)     # streamed: category codes written so far (no batches are kept)
        self._range_writes = -1
        if class_filter and CLASSIFICATION not in {a.name for a in info.attributes}:
            raise ProgressiveError("this cloud has no classification to filter by")
        self.store = PointStore(glc, info.points, capacity=capacity, chunk_points=chunk_points, order=order,
                                classes=class_filter, records=records, position_encoding=position_encoding,
                                placed=streamed)
        self.distribute = DistributePass(glc, self.store)
        self.batch_order = batch_order if self.store.batched and not streamed else batch_boxes.BatchOrder.FILE
        self.assembler = encoding.BatchAssembler(info.points, keep=_copied_rows) if self.store.words else None
        self.reencoded = 0
        """Batches encoded again with points uploaded before (their frame grew): those
        points' positions moved a little, so copies of their records are stale."""
        self.loaded = 0
        self.skipped = 0            # points never drawn: non-finite coordinates or shown value
        self.upload_seconds = 0.0
        self.keep_batches = keep_batches
        self.batches: list[Batch] = []
        self.held: list[AttributeInfo | None] = []
        """The attribute the GPU words of each kept batch hold (None: a mix, while a
        switch was under way when parts of it were encoded again)."""
        self._by_start: list[tuple[int, int]] = []      # (start, index) of the kept batches, in file order
        self._joining: dict[int, tuple[dict[str, np.ndarray], list[int]]] = {}
        """Kept batches part of whose later attributes have come (add_attributes): their
        arrays so far, and how many of their rows those hold."""
        self.joined = 0             # points whose later attributes have joined their kept batch
        self.switch: AttributeSwitch | None = None
        self._percentile: PercentilePass | None = None
        self._range: tuple[float, float] | None = None
        self._range_loaded = 0      # points loaded when the range was taken (0: not taken for this attribute)
        self.finished = False       # no more batches will come (a partial load may end short of the count)

    @property
    def complete(self) -> bool:
        """Every point there will be is on the GPU (streamed: for the view, `settled`)."""
        return self.settled if self.streamed else self.loaded >= self.info.points

    def write_store_batches(self, part: Batch, first: int) -> None:
        """Streamed: the empty store batches first, first + 1, ... hold `part` from now on
        (its points [i·B, (i+1)·B) in the i-th; numbered from `part.start` by their cloud
        indices, which ids report). One write for a node's consecutive batches, each
        write having a fixed cost of its own."""
        at = first * BATCH_POINTS
        self.store.place_run(at, part.start, part.count)
        placed = replace(part, start=at)
        if part.grid is not None and part.grid.runs is not None:      # encoding.node_runs, found as if at 0
            placed = replace(placed, grid=replace(part.grid, runs=part.grid.runs.moved(at)))
        if self.assembler is not None:
            hidden = self._encode_group([(at, part.count, [(placed, 0, part.count)])])
        else:
            hidden = self._upload_records(placed, self.attribute)
            self._add_boxes(placed)
        if self.store.has_classes:
            self._upload_flags(placed, at)
        for i in range(-(-part.count // BATCH_POINTS)):
            # the hidden points go with the first batch: a node's batches are emptied together
            self._written[first + i] = (min(BATCH_POINTS, part.count - i * BATCH_POINTS), hidden if i == 0 else 0)
        if (name := self._category_name()) is not None and name in part.attributes:
            self._codes |= codes_present(part.attributes[name])
        self.loaded += part.count
        self.skipped += hidden
        self.writes += 1

    def clear_store_batches(self, batches) -> None:
        """Streamed: these store batches hold nothing from now on (an evicted node's)."""
        self.store.clear_batches(batches)
        for b in batches:
            count, hidden = self._written.pop(b, (0, 0))
            self.loaded -= count
            self.skipped -= hidden
        self.writes += 1

    def add_batch(self, batch: Batch) -> None:
        t0 = time.perf_counter()
        batch = self._ordered(batch)
        if self.assembler is not None:
            for held, group in self.assembler.add(batch.start, batch.count, batch):
                self._encode_group(group)
                self.reencoded += held is not None and sum(len(pieces) for _, _, pieces in group) > 1
                if held is not None and self.switch is not None and not self.switch.done:
                    self._encoded_again(held)
            # Counted once, for this batch's rows: parts encoded again are not new points.
            self.skipped += _hidden_points(batch, self.attribute, float(self.info.origin[2]))
        else:
            self.skipped += self._upload_records(batch, self.attribute)
            self._add_boxes(batch)
        if self.store.has_classes:
            self._upload_flags(batch, batch.start)
        if self.keep_batches:
            # With its positions or its integers, not both (12 bytes a point of host
            # memory each): a kept batch sent again (hidden points, attribute switching)
            # is encoded from what it keeps.
            bisect.insort(self._by_start, (batch.start, len(self.batches)))
            self.batches.append(replace(batch, grid=None) if batch.grid is not None and batch.xyz is not None else batch)
            self.held.append(self.attribute)
        self.loaded += batch.count
        self.upload_seconds += time.perf_counter() - t0

    def _add_boxes(self, part: Batch) -> None:
        """The float record store's batch boxes grow by a loaded part's (the batched
        layout's, which the rasterizer culls by; the word store's come with its frames)."""
        if self.store.batched:
            self.store.add_boxes(*part_boxes(part))

    def add_attributes(self, part: Batch) -> None:
        """Attributes read after the kept batches (a session's later pass) join them:
        each kept batch that holds points of `part` takes its rows, once every one of its
        rows has come (the later pass's batches need not start where the kept ones do).
        Loader batches only: a kept batch in Morton order would need its order again."""
        if self.batch_order is not batch_boxes.BatchOrder.FILE:
            raise ProgressiveError("attributes read afterwards join batches kept in file order")
        lo, hi = part.start, part.start + part.count
        at = max(0, bisect.bisect_right(self._by_start, (lo, len(self.batches))) - 1)
        found = 0
        for start, k in self._by_start[at:]:
            if start >= hi:
                break
            kept = self.batches[k]
            a, b = max(lo, start), min(hi, start + kept.count)
            if a >= b:
                continue
            found += b - a
            if (a, b) == (start, start + kept.count):
                self._join(k, part.rows(a - lo, b - lo).attributes, part.nonfinite_values)
                continue
            arrays, filled = self._joining.setdefault(k, ({}, [0]))
            for name, values in part.attributes.items():
                into = arrays.setdefault(name, np.empty((kept.count, *values.shape[1:]), dtype=values.dtype))
                into[a - start: b - start] = values[a - lo: b - lo]
            filled[0] += b - a
            if filled[0] == kept.count:
                del self._joining[k]
                self._join(k, arrays, {n: c for n, v in arrays.items() if v.dtype.kind == "f"
                                       and (c := int(np.count_nonzero(~np.isfinite(v))))})
        if found != part.count:
            raise ValueError(f"points {lo:,}..{hi:,} are not all in kept batches (add them first)")

    def _join(self, k: int, attributes: dict[str, np.ndarray], nonfinite: dict[str, int]) -> None:
        kept = self.batches[k]
        self.batches[k] = replace(kept, attributes={**kept.attributes, **attributes},
                                  nonfinite_values={**kept.nonfinite_values,
                                                    **{n: c for n, c in nonfinite.items() if n in attributes}})
        self.joined += kept.count

    def _ordered(self, batch: Batch) -> Batch:
        """The batch as the store takes it: with BatchOrder.MORTON the rows
        batches.sorted_rows says sorted, the store told the way back."""
        if self.batch_order is batch_boxes.BatchOrder.FILE:
            return batch
        rows = batch_boxes.sorted_rows(batch.start, _positions(batch))
        if rows is None:
            return batch
        lo, order = rows
        self.store.reorder(batch.start + lo, (batch.start + lo + order).astype(np.uint32))
        return batch.reordered(lo, lo + order.shape[0], order)

    def _encode_group(self, group: list) -> int:
        """Frame the batches of a group of runs (encoding.BatchAssembler, frame_parts),
        then upload the runs (distribute encodes them in those frames); the points of the
        runs never drawn."""
        parts = [part.rows(lo, hi) for _, _, pieces in group for part, lo, hi in pieces]
        first = group[0][0] // BATCH_POINTS
        k = (group[-1][0] + group[-1][1] - 1) // BATCH_POINTS - first + 1
        self.store.set_frames(first, *frame_parts(parts, first, k, self.info.origin))
        return sum(self._upload_records(part, self.attribute) for part in parts)

    def _upload_records(self, batch: Batch, attribute: AttributeInfo) -> int:
        """Pack the batch's records straight into the distribute pass's staging memory
        and scatter them; the points never drawn (non-finite coordinates or value). The
        word store encodes them in their batches' frames (set already): the batches kept
        as a LAS file's integers are staged as those integers: the distribute pass
        encodes them in their batches' cell frames."""
        kept = self.store.words and batch.grid is not None and batch.count > 0   # a LAS batch may keep its integers
        first = batch.start // BATCH_POINTS
        integer = self.store.integer[first: (batch.start + batch.count - 1) // BATCH_POINTS + 1] if kept \
            else np.zeros(0, dtype=bool)
        if not integer.any():
            words = batch_words(batch, attribute, float(self.info.origin[2]))
            return self.distribute.upload_packed(
                lambda out, lo, hi: pack_into(out, batch, attribute, words, lo, hi, self.distribute.copy),
                batch.count, batch.start)
        if not integer.all():       # batches of both kinds: each run of one kind on its own
            cuts = (first + np.flatnonzero(np.diff(integer)) + 1) * BATCH_POINTS - batch.start
            edges = [0, *cuts.tolist(), batch.count]
            return sum(self._upload_records(batch.rows(lo, hi), attribute) for lo, hi in zip(edges, edges[1:]))
        hides = attribute.kind is AttributeKind.SCALAR
        rgb = _rgb_bytes(batch, attribute)
        shown = rgb if rgb is not None else batch_words(batch, attribute, float(self.info.origin[2]))
        return self.distribute.upload_packed(lambda out, lo, hi: stage_cells(out, batch, shown, hides, lo, hi, self.distribute.copy),
                                             batch.count, batch.start, cells=True, rgb=rgb is not None,
                                             hide_nonfinite=hides)

    def _upload_flags(self, batch: Batch, start: int) -> None:
        """The class and return flags of a batch's points from `start` on: a LAS batch's
        class and return bytes staged as read (the scatter makes the flags), else
        point_flags made here."""
        fields = _class_bytes(batch)
        if fields is None:
            self.distribute.upload_classes(point_flags(batch), start)
            return

        def fill(out: np.ndarray, lo: int, hi: int) -> int:
            flat = _run_of(out)
            for k, values in enumerate(fields):
                flat[k * (hi - lo): (k + 1) * (hi - lo)] = values[lo:hi]
            return 0

        self.distribute.upload_class_bytes(fill, batch.count, start)

    def _encoded_again(self, b: int) -> None:
        """Parts of batch b were encoded again with the attribute shown, during a switch:
        kept loader batches holding them and another attribute now hold a mix (with no
        switch under way every kept batch holds the attribute shown)."""
        lo, hi = b * BATCH_POINTS, (b + 1) * BATCH_POINTS
        at = max(0, bisect.bisect_right(self._by_start, (lo, len(self.batches))) - 1)
        for start, k in self._by_start[at:]:
            if start >= hi:
                break
            if self.held[k] != self.attribute and start + self.batches[k].count > lo:
                self.held[k] = None

    def show_streamed(self, attribute: AttributeInfo) -> None:
        """Streamed: batches written from now on carry `attribute` (the Streamer writes
        every resident node again, or reads them again); its colour range is taken once
        they are."""
        if attribute not in self.info.attributes:
            raise ProgressiveError(f"this cloud has no attribute '{attribute.name}'")
        self.attribute, self._range, self._range_loaded = attribute, None, 0
        self._codes[:] = False

    def begin_switch(self, attribute: AttributeInfo) -> AttributeSwitch:
        """Show `attribute` from now on: batches loaded later are packed with it, and
        stream() rewrites the words of those already on the GPU."""
        if attribute not in self.info.attributes:
            raise ProgressiveError(f"this cloud has no attribute '{attribute.name}'")
        if not self.keep_batches:
            raise ProgressiveError("attribute switching needs the loaded attributes kept (keep_batches)")
        if any(b.records is not None for b in self.batches) and attribute != self.attribute:
            raise ProgressiveError("the fast format stores one attribute; convert again to show another")
        old = self.switch
        previous = (*old.previous, old.attribute) if old and not old.done else (self.attribute,)
        if old is not None and old.next_row:
            self.held[old.order[old.next_batch]] = None     # streamed in part: a mix
        order = [k for _, k in self._by_start]
        self.switch = AttributeSwitch(attribute, previous, len(self.batches), sum(b.count for b in self.batches),
                                      order)
        self.attribute = attribute
        self._range_loaded = 0          # taken anew once the words are rewritten; the last one stays till then
        self.skipped = 0
        return self.switch

    def stream(self, seconds: float = 0.008) -> bool:
        """Rewrite kept batches for the switch in progress for about `seconds` (at least
        one run); True once every loaded point shows the new attribute. Batches whose
        words hold the new attribute already are left as they are; the others go as
        runs of consecutive file indices packed straight into the staging slots."""
        sw = self.switch
        if sw is None or sw.done:
            return True
        t0 = time.perf_counter()
        origin_z = float(self.info.origin[2])
        packer = WordPacker(sw.attribute, origin_z)
        first = sw.next_batch, sw.next_row
        while not sw.done and ((sw.next_batch, sw.next_row) == first or time.perf_counter() - t0 < seconds):
            k = sw.order[sw.next_batch]
            batch, held = self.batches[k], self.held[k]
            if held == sw.attribute:
                self.skipped += _hidden_points(batch, held, origin_z)
                sw.unchanged += batch.count - sw.next_row
                self._streamed(sw, batch.count - sw.next_row)
            elif self._needs_records(batch, held, sw):
                self.skipped += self._upload_records(batch, sw.attribute)
                sw.records += 1
                self.held[k] = sw.attribute
                self._streamed(sw, batch.count)
            else:
                run = self._word_run(sw, packer)
                if run.rgb_bytes:
                    self.distribute.upload_rgb(threaded(run.fill_rgb, self.distribute.copy.pool, PACK_THREADS), run.start,
                                               run.count)
                else:
                    self.distribute.upload_words(threaded(run.fill, self.distribute.copy.pool, PACK_THREADS), run.start,
                                                 run.count)
                self._streamed(sw, run.count, words=True)
        sw.seconds += time.perf_counter() - t0
        return sw.done

    def _needs_records(self, batch: Batch, held: AttributeInfo | None, sw: AttributeSwitch) -> bool:
        """Whole records: a non-finite value of the attribute the words hold (any the
        switches may have left, where they are a mix) or of the new one hides points."""
        held_by = sw.previous if held is None else (held,)
        return any(_hides_points(batch, a) for a in (*held_by, sw.attribute))

    def _word_run(self, sw: AttributeSwitch, packer: WordPacker) -> WordRun:
        """From where the switch stands, the kept batches that follow each other in file
        order and need only their words, up to one staging piece of words."""
        room = self.distribute.word_piece_items()
        parts, at, i, row = [], None, sw.next_batch, sw.next_row
        while i < sw.batches and room > 0:
            k = sw.order[i]
            batch, held = self.batches[k], self.held[k]
            if parts and (batch.start != at or held == sw.attribute or self._needs_records(batch, held, sw)):
                break
            take = min(room, batch.count - row)
            parts.append((batch, row, row + take))
            room, at, i, row = room - take, batch.start + batch.count, i + 1, 0
        return WordRun(packer, parts)

    def _streamed(self, sw: AttributeSwitch, n: int, words: bool = False) -> None:
        """The switch moves on n points; a batch whose words were streamed and is done
        holds the new attribute (its points never drawn: those of its coordinates)."""
        while n > 0:
            k = sw.order[sw.next_batch]
            batch = self.batches[k]
            take = min(n, batch.count - sw.next_row)
            sw.next_row += take
            sw.streamed += take
            n -= take
            if sw.next_row == batch.count:
                if words:
                    self.skipped += batch.nonfinite_positions
                    self.held[k] = sw.attribute
                sw.next_batch, sw.next_row = sw.next_batch + 1, 0

    def drawable(self, hidden: frozenset[int]) -> frozenset[int]:
        """Category codes to leave out: with the classes kept, always; else only while a
        category attribute is shown (its word is the code)."""
        keeps = self.store.has_classes or self.attribute.kind is AttributeKind.CATEGORY
        return frozenset(hidden) if keeps else frozenset()

    def drawable_returns(self, returns: Returns) -> Returns:
        """Return filters need the kept point flags; without them every return draws."""
        return returns if self.store.has_classes else Returns.ALL

    def categories(self) -> list[int]:
        """Codes present in the kept batches (streamed: in every node written so far): of
        the classification where the classes are kept, else of the shown category
        attribute."""
        name = self._category_name()
        if name is None:
            return []
        if self.streamed:
            return np.flatnonzero(self._codes).tolist()
        seen = np.zeros(256, dtype=bool)
        for b in self.batches:
            shown = b.records is not None and name == self.attribute.name
            values = b.records[:, 3] if shown else b.attributes.get(name)
            if values is not None:
                seen |= codes_present(values)
        return np.flatnonzero(seen).tolist()

    def _category_name(self) -> str | None:
        """The attribute whose codes categories() lists: the classification where the
        classes are kept, else the shown category attribute (None: neither)."""
        if self.store.has_classes:
            return CLASSIFICATION
        return self.attribute.name if self.attribute.kind is AttributeKind.CATEGORY else None

    @property
    def positions_changed(self) -> bool:
        """The switch in progress rewrote whole records: which points are drawn changed."""
        return self.switch is not None and self.switch.records > 0

    def value_range(self) -> tuple[float, float] | None:
        """The colour contract's range of a scalar: the 1st and 99th percentiles (numpy's
        linear method) of the stored values of every drawn point, exact. Taken after the
        first batch, whenever the loaded points have grown RANGE_GROWTH times since, and
        when loading completes (or ends short: `finished`); during an attribute switch the last one stays until the
        words are all rewritten. None for other kinds, or with no finite value loaded."""
        if self.attribute.kind is not AttributeKind.SCALAR:
            return None
        switching = self.switch is not None and not self.switch.done
        grown = self.loaded >= RANGE_GROWTH * self._range_loaded or self.complete or self.finished
        # a streamed cloud's points change without growing: taken anew when they changed
        fresh = self.writes != self._range_writes if self.streamed else self.loaded > self._range_loaded
        if not switching and fresh and grown and self.loaded > 0:
            self._percentile = self._percentile or PercentilePass(self.glc, self.store)
            self._range, self._range_loaded, self._range_writes = self._percentile.run(), self.loaded, self.writes
        return self._range

    def style(self, colormap: Colormap = Colormap.VIRIDIS, background=(0, 0, 0),
              value_range: tuple[float, float] | None = None, palette: Palette = DEFAULT_PALETTE) -> ColorStyle:
        """`value_range`: scalar values (less the attribute's offset) at the colormap's
        ends; None: the contract's range, which `resolved` keeps current. `palette`:
        the colours of category codes."""
        automatic = value_range is None
        taken = self.value_range() if automatic else value_range
        return ColorStyle.for_attribute(self.attribute, taken or NO_RANGE, colormap, background, automatic=automatic,
                                        palette=palette)

    def resolved(self, style: ColorStyle) -> ColorStyle:
        """`style` with its automatic range as it stands now (renderers call this after
        distributing, so an image shows the range of the points it was drawn from)."""
        if not style.automatic or style.mode is not ColorMode.SCALAR:
            return style
        return replace(style, value_range=self.value_range() or NO_RANGE)

    def release(self) -> None:
        if self._percentile is not None:
            self._percentile.release()
        self.distribute.release()
        self.store.release()
        self.batches.clear()
        self.held.clear()
        self._by_start.clear()


CLASSIFICATION = "classification"


FIRST_RETURN, LAST_RETURN = 0x100, 0x200
"""Point flag bits beside the class byte (shaders/classes.glsl)."""


def codes_present(values: np.ndarray) -> np.ndarray:
    """(256,) bool: which category codes occur in `values`, codes over 255 counted as
    255 (the shaders' clamp). Unsigned codes are counted (np.bincount: a quarter of
    np.unique's time on a node's 40,000 classes, which the frame loop pays per node);
    others, which may be negative, go through np.unique and keep only 0..255."""
    if values.dtype.kind == "u":
        return np.bincount(np.minimum(values, 255).astype(np.uint8, copy=False), minlength=256) > 0
    seen = np.zeros(256, dtype=bool)
    codes = np.unique(np.minimum(values, 255))
    seen[codes[codes >= 0]] = True
    return seen


def point_flags(batch: Batch) -> np.ndarray:
    """Each point's 16 flag bits: its class (a fast-format file that has classification
    stores it as its one attribute word), whether it is its pulse's first and last
    return (a point without return numbers is both)."""
    if batch.records is not None:
        codes = batch.records[:, 3]
    else:
        codes = batch.attributes[CLASSIFICATION]
    flags = np.minimum(np.asarray(codes, dtype=np.uint32), 255)
    number, count = batch.attributes.get("return_number"), batch.attributes.get("number_of_returns")
    if number is None or count is None:
        return flags | np.uint32(FIRST_RETURN | LAST_RETURN)
    number, count = np.asarray(number), np.asarray(count)
    return (flags | np.where(number <= 1, FIRST_RETURN, 0).astype(np.uint32)
            | np.where(number >= count, LAST_RETURN, 0).astype(np.uint32))


def _class_bytes(batch: Batch) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """A loaded batch's class, return number and number of returns, each a uint8 per
    point (a LAS or LAZ file's), from which the scatter makes point_flags' flags; None
    where it holds them otherwise (then point_flags makes them)."""
    if batch.records is not None:
        return None
    fields = tuple(batch.attributes.get(name) for name in (CLASSIFICATION, "return_number", "number_of_returns"))
    if any(v is None or v.dtype != np.uint8 or v.ndim != 1 for v in fields):
        return None
    return fields


def _copied_rows(batch: Batch, lo: int, hi: int) -> Batch:
    """Rows lo..hi of a batch with arrays of their own (what the assembler holds)."""
    part = batch.rows(lo, hi)
    grid = None if part.grid is None else replace(part.grid, cells=part.grid.cells.copy())
    return replace(part, xyz=None if part.xyz is None else part.xyz.copy(), attributes={k: v.copy() for k, v in part.attributes.items()},
                   records=None if part.records is None else part.records.copy(), grid=grid)


def frame_parts(parts: list[Batch], first: int, k: int, origin: np.ndarray) -> tuple:
    """Frames of batches first .. first + k - 1 holding `parts` (numbered by their store
    positions): by the boxes of their points, or by their integers where every part is of
    one LAS grid whose batches span under 2^30 cells. (frames, boxes, least, shift) as
    PointStore.set_frames takes them (least, shift None: framed by the boxes). The boxes
    of one LAS grid's parts come from their least and most integers (encoding.cell_boxes),
    those of fast-format parts from the boxes their parser found (encoding.with_runs):
    either way without a pass over the positions on this thread."""
    grids = {(p.grid.scale, p.grid.offset) if p.grid is not None else None for p in parts}
    if len(grids) == 1 and None not in grids:
        least, most = np.full((k, 3), np.iinfo(np.int64).max), np.full((k, 3), np.iinfo(np.int64).min)
        for part in parts:
            at, lo, hi = encoding.cell_range(part.grid, part.start)
            least[at - first: at - first + lo.shape[0]] = np.minimum(least[at - first: at - first + lo.shape[0]], lo)
            most[at - first: at - first + hi.shape[0]] = np.maximum(most[at - first: at - first + hi.shape[0]], hi)
        scale, offset = next(iter(grids))
        if (boxes := encoding.cell_boxes(least, most, scale, offset, origin)) is not None:
            if not (most - least < encoding.CELLS).all():
                return encoding.frames_from_boxes(boxes), boxes, None, None
            shift = encoding.cell_shifts(least, most)
            return encoding.integer_frames(least, shift, scale, offset, origin), boxes, least, shift
    boxes = batch_boxes.empty_boxes(k)
    for part in parts:
        at, new = part_boxes(part)
        batch_boxes.merge(boxes, at - first, new)
    return encoding.frames_from_boxes(boxes), boxes, None, None


def part_boxes(part: Batch) -> tuple[int, np.ndarray]:
    """The first store batch a loaded part touches and the boxes of its points in each
    (batches.boxes_of): those its parser found (encoding.with_runs) where they are of
    its rows, else a LAS part's from the least and most of its integers
    (encoding.cell_boxes), else from its positions."""
    runs = part.boxes
    if runs is not None and runs.of(part.start, part.count, BATCH_POINTS):
        return runs.first, batch_boxes.boxes_from_runs(runs)
    if part.grid is not None and part.count and part.nonfinite_positions == 0:      # no positions computed
        first, least, most = encoding.cell_range(part.grid, part.start)
        boxes = encoding.cell_boxes(least, most, part.grid.scale, part.grid.offset, part.grid.origin)
        if boxes is not None:
            return first, boxes
    return batch_boxes.boxes_of(_positions(part), part.start, _all_finite(part))


def stage_cells(out: np.ndarray, batch: Batch, shown: np.ndarray, hides: bool, lo: int, hi: int,
                copy: StageCopier) -> int:
    """Rows [lo, hi) of a LAS batch staged as the distribute pass encodes them
    (shaders/distribute.comp STAGED_CELLS): their X, Y, Z as the file has them, then
    what they show, each one copy into `out` ((hi - lo, 4) uint32, read as one run of
    words): `shown` the batch's attribute words, or (n, 3) uint8 its R, G, B bytes
    (_rgb_bytes; the scatter makes the words). The points never drawn: with `hides` (a
    shown scalar), those whose word is not finite."""
    n = hi - lo
    flat = _run_of(out)
    copy(flat[:3 * n].reshape(n, 3), batch.grid.cells[lo:hi].astype(np.int32, copy=False).view(np.uint32))
    if shown.ndim == 2:
        copy(flat[3 * n:].view(np.uint8)[:3 * n].reshape(n, 3), shown[lo:hi])
        return 0
    copy(flat[3 * n:], shown[lo:hi])
    return int(np.count_nonzero((shown[lo:hi] & EXPONENT) == EXPONENT)) if hides else 0


def _run_of(out: np.ndarray) -> np.ndarray:
    """A fill's staging rows as one run (a view: a fill that stages fields one after
    another writes through it)."""
    if not out.flags.c_contiguous:
        raise ValueError("fields are staged into one contiguous run")
    return out.reshape(-1)


def _rgb_bytes(batch: Batch, attribute: AttributeInfo) -> np.ndarray | None:
    """A loaded batch's colours as (n, 3) uint8 (the loaders' 8-bit channels), where the
    attribute shown is RGB and they are held so; else None."""
    if attribute.kind is not AttributeKind.RGB or batch.records is not None:
        return None
    values = batch.attributes[attribute.name]
    return values if values.dtype == np.uint8 and values.ndim == 2 and values.shape[1] == 3 else None


def _hidden_points(batch: Batch, attribute: AttributeInfo, origin_z: float) -> int:
    """Points of a batch never drawn, as pack_into counts them: a coordinate not finite,
    or a shown scalar not finite (a fast-format batch's only where it says it has such)."""
    finite = _all_finite(batch)
    hides = attribute.kind is AttributeKind.SCALAR and (batch.records is None or batch.nonfinite_values.get(attribute.name))
    if hides and batch.records is None and attribute.name != ELEVATION:
        hides = batch.attributes[attribute.name].dtype.kind == "f"     # an integer's word is always finite
    elif hides and attribute.name == ELEVATION and finite:
        hides = not _elevation_ends_finite(batch, attribute, origin_z)
    if finite and not hides:
        return 0
    shown = np.isfinite(_positions(batch)).all(axis=1) if not finite else np.ones(batch.count, dtype=bool)
    if hides:
        shown &= (batch_words(batch, attribute, origin_z) & EXPONENT) != EXPONENT
    return int(batch.count - np.count_nonzero(shown))


def _elevation_ends_finite(batch: Batch, attribute: AttributeInfo, origin_z: float) -> bool:
    """Whether the elevation words of a batch's least and greatest z (its float64 bounds,
    which its positions were rounded from: every loader's but the fast format's) are
    finite, and so every one of its words (a word is monotonic in z: scaling, rounding
    and adding a constant are), without a pass over its points; False without bounds."""
    if batch.bounds is None:
        return False
    with np.errstate(over="ignore", invalid="ignore"):
        ends = (np.stack(batch.bounds) - [0.0, 0.0, origin_z]).astype(np.float32)
    return bool(((attribute_word(Batch(start=0, xyz=ends), attribute, origin_z) & EXPONENT) != EXPONENT).all())


def _all_finite(batch: Batch) -> bool:
    """Every coordinate of the batch finite: none where its loader counted none (the
    count of a batch's rows is the whole batch's, so only a nonzero one needs a look),
    else a pass over the positions (a fast-format batch's one contiguous pass over its
    records: its positions are a strided view). So the frame loop's thread makes no pass
    over a LAS batch's positions."""
    if batch.nonfinite_positions == 0:
        return True
    if batch.records is not None:
        return nonfinite_records(batch.records)[0] == 0
    return batch_boxes.all_finite(batch.positions)


def _positions(batch: Batch) -> np.ndarray:
    return batch.positions if batch.records is None else batch.records[:, :3].view(np.float32)


def _hides_points(batch: Batch, attribute: AttributeInfo) -> bool:
    """pack_records gives NaN coordinates to points whose shown scalar is not finite."""
    return attribute.kind is AttributeKind.SCALAR and bool(batch.nonfinite_values.get(attribute.name))
