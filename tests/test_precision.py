"""Positions as 30-bit words relative to their batch (progressive/encoding.py): the
numpy twin against plain integer arithmetic, the batch assembler over any split and
order, the GPU's frames and adaptive word choice against the twin, and the adaptive
render's error bound against the float64 projection of laspy's coordinates."""

from __future__ import annotations

import json

import laspy
import numpy as np
import pytest

from conftest import SAMPLE, file_xyz, shared_file
from progressive import batches, encoding
from progressive.attributes import find_attribute
from progressive.camera import Camera, Projection, auto_camera, screen_points, view_uniforms
from progressive.encoding import Encoding, Precision
from progressive.loaders import CloudLoader
from progressive.permutation import BATCH_POINTS
from progressive.reference import EMPTY
from progressive.renderer import Raster, Renderer

W, H = 160, 120


def test_words_hold_ten_bits_of_each_axis_a_level():
    rng = np.random.default_rng(1)
    q = rng.integers(0, encoding.CELLS, (1000, 3))
    words = encoding.pack_words(q)
    for level in range(3):
        shift = 10 * (2 - level)
        for axis in range(3):
            assert np.array_equal((words[:, level] >> (10 * (2 - axis))) & 1023, (q[:, axis] >> shift) & 1023)
    assert (words < 2**30).all()
    assert np.array_equal(encoding.unpack_cells(words), q)
    for levels in (1, 2):
        cell = 1 << (10 * (3 - levels))
        assert np.array_equal(encoding.unpack_cells(words, levels), q // cell * cell + cell // 2)


def test_hidden_points_get_the_hidden_word():
    q = encoding.quantize(np.array([[1, 2, 3], [np.nan, 0, 0], [4, np.inf, 6]], dtype=np.float32),
                          encoding.empty_frames(1) + 1)
    words = encoding.pack_words(q)
    assert (words[0] != encoding.HIDDEN_WORD).all() and (words[1:] == encoding.HIDDEN_WORD).all()
    assert np.isnan(encoding.decode_frames(words, np.repeat(encoding.empty_frames(1) + 1, 3, 0))[1:]).all()


def test_frames_cover_their_boxes_and_quantize_within_half_a_cell():
    rng = np.random.default_rng(2)
    p = (rng.normal(0, 50, (BATCH_POINTS * 3, 3)) + [1e5, -2e3, 7]).astype(np.float32)
    p[:BATCH_POINTS, 2] = 3.5                                       # a flat batch
    first, boxes = batches.boxes_of(p, 0)
    frames = encoding.frames_from_boxes(boxes)
    lo, hi = boxes[:, 0:3].astype(np.float64), boxes[:, 4:7].astype(np.float64)
    assert np.array_equal(frames[:, 0:3], boxes[:, 0:3])
    assert (lo + frames[:, 4:7].astype(np.float64) * (encoding.CELLS - 1) >= hi).all()
    per_point = frames[np.arange(p.shape[0]) // BATCH_POINTS]
    q = encoding.quantize(p, per_point)
    assert (q >= 0).all() and (q < encoding.CELLS).all()
    exact = (p.astype(np.float64) - per_point[:, 0:3]) / per_point[:, 4:7]
    assert np.abs(q - exact).max() <= 0.5 + 1e-6
    decoded = encoding.decode_frames(encoding.pack_words(q), per_point)
    # float(q) (over 2^24), the product and the sum each round once, at magnitudes <= |base| + |p|
    assert (np.abs(decoded - p) <= 2 * np.spacing(np.abs(per_point[:, 0:3]) + np.abs(p)) + per_point[:, 4:7]).all()


@pytest.mark.parametrize("seed", range(6))
def test_assembler_encodes_every_point_and_ends_each_batch_whole(seed):
    """Any split, any order: every point goes out at least once, a batch's last group
    holds all its points, and only the incomplete batch of a short load stays held."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(3, 6) * BATCH_POINTS + rng.integers(0, BATCH_POINTS))
    cuts = np.unique(rng.integers(1, n, int(rng.integers(0, 12))))
    parts = list(zip([0, *cuts], [*cuts, n]))
    short = seed % 2 == 1
    if short:
        parts = parts[:-1] if len(parts) > 1 else [(0, n // 2)]
    rng.shuffle(parts)
    assembler = encoding.BatchAssembler(n)
    seen = np.zeros(n, dtype=bool)
    last: dict[int, np.ndarray] = {}
    for a, b in parts:
        for held, group in assembler.add(a, b - a, (a, b)):
            covered = []
            for start, count, pieces in group:
                rows = np.concatenate([np.arange(part[0] + lo, part[0] + hi) for part, lo, hi in pieces])
                assert np.array_equal(rows, np.arange(start, start + count))
                covered.append(rows)
            rows = np.concatenate(covered)
            seen[rows] = True
            for batch in np.unique(rows // BATCH_POINTS):
                last[int(batch)] = rows[rows // BATCH_POINTS == batch]
            if held is None:
                assert all(np.isin(np.arange(k * BATCH_POINTS, min(n, (k + 1) * BATCH_POINTS)), rows).all()
                           for k in np.unique(rows // BATCH_POINTS))
    loaded = np.zeros(n, dtype=bool)
    for a, b in parts:
        loaded[a:b] = True
    assert np.array_equal(seen, loaded)
    for batch, rows in last.items():
        members = np.arange(batch * BATCH_POINTS, min(n, (batch + 1) * BATCH_POINTS))
        assert np.array_equal(np.sort(rows), members[loaded[members]])
    incomplete = sum(int(loaded[k * BATCH_POINTS: (k + 1) * BATCH_POINTS].sum()) for k in range(-(-n // BATCH_POINTS))
                     if not loaded[k * BATCH_POINTS: (k + 1) * BATCH_POINTS].all())
    assert assembler.held == incomplete
    assert short or assembler.held == 0


def load(gl, path, *, position_encoding=Encoding.WORDS, batch_points=30_000, reverse=True):
    with CloudLoader([path], batch_points=batch_points) as loader:
        info = loader.info
        r = Renderer(gl, info, find_attribute(info, "elevation"), raster=Raster.COMPUTE32, width=W, height=H,
                     position_encoding=position_encoding)
        loader.start()
        for batch in sorted(loader, key=lambda b: b.start, reverse=reverse):
            r.add_batch(batch)
    gl.check()
    return r, info


def views(info) -> dict[str, Camera]:
    lo, hi = info.bounds_min, info.bounds_max
    base = auto_camera(lo, hi, W / H)
    size = hi - lo
    near = Camera(position=tuple(lo + [0.3 * size[0], 0.3 * size[1], 0.5 * size[2] + 30]),
                  target=tuple(lo + [0.5 * size[0], 0.5 * size[1], 0.5 * size[2]]), near=0.5, far=1e5)
    ortho = Camera(position=tuple((lo + hi) / 2 + [0, 0, 500]), target=tuple((lo + hi) / 2), up=(0, 1, 0),
                   projection=Projection.ORTHOGRAPHIC, height=float(size[1]), near=1.0, far=1e4)
    return {"overview": base, "close": near, "plan": ortho}


@pytest.mark.parametrize("name", ["overview", "close", "plan"])
def test_cull_flags_are_the_twins_word_choice(gl, name):
    r, info = load(gl, SAMPLE)
    try:
        cam = views(info)[name]
        view = view_uniforms(cam, info.origin, W, H)
        r.raster.precision = Precision.ADAPTIVE
        r.raster.begin_frame(view)
        flags = np.frombuffer(r.raster.culling.flags.read(), dtype=np.uint32)
        shown = batches.in_view(r.store.boxes, view)
        levels = encoding.levels_needed(r.store.frames, batches.least_depths(r.store.boxes, view), view)
        assert np.array_equal(flags, np.where(shown, levels, 0))
        r.raster.precision = Precision.EXACT
        r.raster.begin_frame(view)
        flags = np.frombuffer(r.raster.culling.flags.read(), dtype=np.uint32)
        assert np.array_equal(flags, np.where(shown, 3, 0))
    finally:
        r.release()


@pytest.mark.parametrize("path", [SAMPLE, "vegetation_1_3.las", "pine_plot.laz"], ids=lambda p: getattr(p, "name", p))
def test_adaptive_render_keeps_every_point_within_its_bound(gl, path):
    """Each pixel of an adaptive render shows a point whose exact position (laspy's
    coordinates, float64) projects within ADAPTIVE_ERROR_PX of that pixel, and the
    views read fewer than all words somewhere (so the bound is tested)."""
    path = path if path == SAMPLE else shared_file(path)
    r, info = load(gl, path)
    xyz = file_xyz(path)
    coarse = 0
    try:
        for cam in views(info).values():
            frame = r.render(cam, W, H, r.style(), precision=Precision.ADAPTIVE)
            shown = frame.ids != EMPTY
            assert shown.sum() > 100
            rows, cols = np.nonzero(shown)
            xy, _ = screen_points(cam, xyz[frame.ids[shown]], W, H)
            dx = np.maximum(0, np.maximum(cols - xy[:, 0], xy[:, 0] - (cols + 1)))
            dy = np.maximum(0, np.maximum(rows - xy[:, 1], xy[:, 1] - (rows + 1)))
            assert np.hypot(dx, dy).max() <= encoding.ADAPTIVE_ERROR_PX + 1e-3
            flags = np.frombuffer(r.raster.culling.flags.read(), dtype=np.uint32)
            coarse += int(np.count_nonzero((flags > 0) & (flags < 3)))
            exact = r.render(cam, W, H, r.style(), precision=Precision.EXACT)
            assert np.mean(exact.ids == frame.ids) > 0.5     # nearly the same image, not the same
        assert coarse > 0
    finally:
        r.release()


def test_word_store_renders_the_float_stores_ids(gl):
    """Exact precision: the word store's render has the float record store's ids
    (both meet the render contract; positions differ only in float32 rounding)."""
    words, info = load(gl, SAMPLE)
    floats, _ = load(gl, SAMPLE, position_encoding=Encoding.FLOAT)
    try:
        assert words.store.words and not floats.store.words
        for cam in views(info).values():
            a = words.render(cam, W, H, words.style())
            b = floats.render(cam, W, H, floats.style())
            assert np.mean(a.ids == b.ids) >= 0.999
    finally:
        words.release()
        floats.release()


def test_cli_reports_precision_and_the_words_read(tmp_path):
    from progressive.cli import main

    out = {}
    for precision in ("exact", "adaptive"):
        stats = tmp_path / f"{precision}.json"
        assert main(["render", "--width", str(W), "--height", str(H), "--precision", precision,
                     "--stats", str(stats), "--ids", str(tmp_path / f"{precision}.npy")]) == 0
        out[precision] = json.loads(stats.read_text())
    assert out["exact"]["precision"] == "exact" and out["adaptive"]["precision"] == "adaptive"
    drawn = out["adaptive"]["batches"]["drawn"]
    assert sum(out["adaptive"]["batches"]["bits"].values()) == drawn
    assert out["exact"]["batches"]["bits"]["30"] == drawn
    assert out["adaptive"]["batches"]["bits"]["30"] < drawn
    assert main(["render", "--precision", "rough", "--out", str(tmp_path / "x.png")]) == 2


@pytest.mark.parametrize("extra", [[], ["--converge"]])
def test_adaptive_precision_needs_brute_force(tmp_path, capsys, extra):
    """Progressive frames reproject each point at its exact position (a coarse fill
    would leave points where they were not drawn): one line, exit 2, nothing written;
    the Session refuses it too."""
    from progressive.cli import main
    from progressive.errors import ProgressiveError
    from progressive.session import Method, Session, SessionOptions

    code = main(["render", "--method", "progressive", *extra, "--precision", "adaptive",
                 "--out", str(tmp_path / "x.png")])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("progressive: error:") and "--method brute" in err[0]
    assert not (tmp_path / "x.png").exists()
    with pytest.raises(ProgressiveError, match="brute"):
        Session([SAMPLE], SessionOptions(method=Method.PROGRESSIVE, precision=Precision.ADAPTIVE))


def test_stats_count_coarse_words_only_where_the_raster_reads_them(tmp_path):
    """GL_POINTS reads every word: --stats says so under adaptive precision too."""
    from progressive.cli import main

    stats = tmp_path / "s.json"
    assert main(["render", "--width", str(W), "--height", str(H), "--raster", "points", "--precision", "adaptive",
                 "--stats", str(stats), "--out", str(tmp_path / "x.png")]) == 0
    counts = json.loads(stats.read_text())["batches"]
    assert counts["bits"]["30"] == counts["drawn"] > 0


def test_files_of_two_grids_frame_the_batch_they_share_by_its_box(gl, tmp_path):
    """The sample and a copy of it on a grid 10× finer, one cloud: the batch holding both
    files' points is framed by its box, every other by its file's integers; the render
    meets the contract, and uploading a loader batch of both kinds again (attribute
    switching does for hidden points) leaves the words as they were."""
    src = laspy.read(SAMPLE)
    header = laspy.LasHeader(point_format=src.header.point_format, version=src.header.version)
    header.scales, header.offsets = src.header.scales / 10, src.header.offsets + [1000.0, 0.0, 0.0]
    fine = laspy.LasData(header)
    fine.x, fine.y, fine.z = src.x + 1000.0, src.y, src.z
    for name in src.point_format.dimension_names:
        if name not in ("X", "Y", "Z"):
            fine[name] = src[name]
    copy = tmp_path / "fine.las"
    fine.write(copy)
    with CloudLoader([SAMPLE, copy], batch_points=30_000) as loader:
        info = loader.info
        loader.start()
        scene_batches = sorted(loader, key=lambda b: b.start)
    r = Renderer(gl, info, find_attribute(info, "elevation"), raster=Raster.COMPUTE32, width=W, height=H)
    try:
        for b in scene_batches:
            r.add_batch(b)
        count = -(-info.points // BATCH_POINTS)
        held = r.store.file_indices(np.arange(info.points))     # the batch order may sort a loaded batch's rows
        first_file = np.zeros(count, bool)
        second_file = np.zeros(count, bool)
        first_file[np.arange(info.points)[held < src.header.point_count] // BATCH_POINTS] = True
        second_file[np.arange(info.points)[held >= src.header.point_count] // BATCH_POINTS] = True
        shared = first_file & second_file
        assert shared.sum() == 1 and np.array_equal(r.store.integer[:count], ~shared)
        xyz = np.concatenate([file_xyz(SAMPLE), file_xyz(copy)])
        cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
        slots = r.store.slots_of(np.arange(info.points)).astype(np.int64)
        frame = r.render(cam, W, H, r.style())
        from progressive.reference import reference_ids
        assert np.mean(frame.ids == reference_ids(xyz, cam, W, H, tie_key=slots)) >= 0.999
        before = r.store.raw_words()
        mixed = next(b for b in scene_batches if b.start == src.header.point_count)     # batch `shared`, then integer ones
        r.scene._upload_records(r.scene._ordered(mixed), r.scene.attribute)     # as the store took it
        assert np.array_equal(r.store.raw_words(), before)
    finally:
        r.release()


def test_word_store_takes_16_bytes_a_point_and_under_one_percent_more(gl):
    """GPU memory: four planes of 4 bytes a slot, in whole blocks (the last one padded:
    under 64 KiB, against 16 GB at 1 B points), and the batches' boxes, frames and cull
    flags under 1 % of it (the issue's target), read from the buffers' sizes."""
    from progressive.pointstore import BLOCK_RECORDS

    r, info = load(gl, SAMPLE)
    try:
        store = r.store
        points = sum(b.size for b in store.buffers)
        assert store.chunks == len(store.buffers) == 1
        assert points == 16 * (store.capacity + (-store.capacity) % BLOCK_RECORDS)
        metadata = store.box_buffer.size + store.frame_buffer.size + store.layout_buffer.size + r.raster.culling.flags.size
        assert metadata <= 0.01 * points
    finally:
        r.release()
