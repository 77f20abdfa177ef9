"""COPC: `convert` writes it (every point and attribute back through laspy's CopcReader,
a hierarchy laspy walks node by node), and a cloud larger than the GPU memory limit
keeps whole octree levels from the root down (against laspy's level queries), or with a
view the nodes it needs most (against laspy's hierarchy and node bounds)."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import struct

import laspy
import numpy as np
import pytest
from laspy.copc import load_octree_for_query

from conftest import BUNNY, SAMPLE, shared_file
from progressive import memory
from progressive.camera import Camera
from progressive.cli import main
from progressive.loaders import CloudLoader, copc_write
from progressive.loaders.copc import ENTRY, is_copc, keep_levels, open_copc
from progressive.loaders.las import open_las
from progressive.permutation import LAYOUT, Permutation
from progressive.reference import subset_reference_ids

W, H = 160, 120
SMALL = ["--width", str(W), "--height", str(H)]
WAVEFORM = {"wavepacket_index", "wavepacket_offset", "wavepacket_size", "return_point_wave_location",
            "x_t", "y_t", "z_t"}
SCAN_STEP = 0.006


def limit_for(points: int) -> int:
    """A --gpu-memory-limit with room for exactly `points` points at W x H."""
    return memory.bytes_for(points, W * H)


def nodes_of(path) -> list:
    """laspy's walk of the whole hierarchy: every node it reaches from the root."""
    with laspy.CopcReader.open(path) as reader:
        return load_octree_for_query(reader.source, reader.copc_info, reader.root_page)


def convert(tmp_path, *inputs, name="out.copc.laz", capsys=None) -> os.PathLike:
    out = tmp_path / name
    code = main(["convert", *map(str, inputs), str(out)])
    captured = capsys.readouterr() if capsys else None
    assert code == 0, captured.err if captured else code
    return out


def columns(points, names) -> np.ndarray:
    """The named dimensions as float64 columns (scan angles in degrees), one row a point."""
    cols = []
    for n in names:
        if n == "scan_angle_rank":
            cols.append(np.asarray(points[n], np.float64))
        elif n == "scan_angle":
            cols.append(np.asarray(points[n], np.float64) * SCAN_STEP)
        else:
            v = np.asarray(points[n], np.float64)
            cols.extend(v.reshape(len(v), -1).T)
    return np.stack(cols, axis=1)


def sorted_rows(rows: np.ndarray) -> np.ndarray:
    return rows[np.lexsort(rows.T[::-1])]


def expected_names(source: laspy.LasData) -> list[str]:
    """The input's dimensions the COPC file must hold (waveform fields are not in 6-8)."""
    return [n for n in source.point_format.dimension_names if n not in WAVEFORM]


def assert_same_points(source_paths, out) -> None:
    """Every input point, with every attribute, is in the COPC file as laspy's CopcReader
    reads it (as a multiset: the file is in octree order); scan angles in whole degrees
    within half a 0.006° step."""
    sources = [laspy.read(p) for p in source_paths]
    names = expected_names(sources[0])
    with laspy.CopcReader.open(out) as reader:
        back = reader.query()
        assert reader.header.point_format.id in (6, 7, 8)
    out_names = ["scan_angle" if n == "scan_angle_rank" else n for n in names]
    for n in out_names:
        assert n in back.point_format.dimension_names, n
    want = sorted_rows(np.concatenate([columns(s.points, names) for s in sources]))
    got = sorted_rows(columns(back, out_names))
    assert got.shape == want.shape
    angle = [i for i, n in enumerate(names) if n == "scan_angle_rank"]
    exact = [i for i in range(want.shape[1]) if i not in angle]
    # sorting puts the angles' rounding inside rows whose other columns are equal first
    np.testing.assert_array_equal(got[:, exact], want[:, exact])
    if angle:
        assert np.abs(got[:, angle] - want[:, angle]).max() <= SCAN_STEP / 2 + 1e-9


def assert_valid_hierarchy(out) -> None:
    """laspy reaches every node from the root; each node's points lie in its cube; the
    points of the nodes add up to the header's count; the info VLR's cube holds the
    bounds; and the file read as plain LAZ holds the nodes' points in file order."""
    nodes = nodes_of(out)
    plain = laspy.read(out)
    with laspy.CopcReader.open(out) as reader:
        info, header = reader.copc_info, reader.header
        assert type(header.vlrs[0]).__name__ == "CopcInfoVlr"
        assert sum(n.point_count for n in nodes) == header.point_count == len(plain.points)
        lo, hi = info.center - info.halfsize, info.center + info.halfsize
        assert np.all(lo <= header.mins) and np.all(header.maxs <= hi) and info.spacing > 0
        for node in nodes:
            pts = reader._fetch_and_decompress_points_of_nodes([node])
            assert len(pts) == node.point_count > 0
            xyz = np.stack([pts.x, pts.y, pts.z], axis=1)
            b = node.key.bounds(laspy.copc.Bounds(lo, hi))
            slack = header.scales
            assert np.all(xyz >= b.mins - slack) and np.all(xyz <= b.maxs + slack), node
        ordered = sorted(nodes, key=lambda n: n.offset)
        back = reader._fetch_and_decompress_points_of_nodes(ordered)
    np.testing.assert_array_equal(back.array, plain.points.array)
    levels = {n.key.level for n in nodes}
    assert levels == set(range(len(levels)))


ROUND_TRIPS = ["autzen_trim.las", "extrabytes.las", "las_with_several_extra_byte_bloc.laz", "fullwave.laz",
               "lion_takanawa.copc.laz", "TO_core_last_zoom.laz", "pine_plot.laz", "vegetation_1_3.las"]


@pytest.mark.parametrize("name", ROUND_TRIPS)
def test_convert_round_trips_every_point_and_attribute(tmp_path, capsys, name):
    path = SAMPLE if name == "autzen_trim.las" else shared_file(name)
    out = convert(tmp_path, path, capsys=capsys)
    assert is_copc(out)
    assert_same_points([path], out)
    assert_valid_hierarchy(out)
    source, back = laspy.read(path), laspy.read(out)
    np.testing.assert_array_equal(back.header.scales, source.header.scales)
    np.testing.assert_array_equal(back.header.offsets, source.header.offsets)
    np.testing.assert_array_equal(back.header.mins, np.array([source.x.min(), source.y.min(), source.z.min()]))
    np.testing.assert_array_equal(back.header.maxs, np.array([source.x.max(), source.y.max(), source.z.max()]))
    returns = np.bincount(np.asarray(source.return_number), minlength=16)[1:16]
    np.testing.assert_array_equal(back.header.number_of_points_by_return, returns)
    if source.header.parse_crs() is not None:
        assert back.header.parse_crs() == source.header.parse_crs()


def test_convert_several_files_and_a_large_one(tmp_path, capsys):
    """wires (1.7 M points) and the sample: one cloud, a hierarchy of several levels."""
    wires = shared_file("wires.laz")
    out = convert(tmp_path, wires, capsys=capsys)
    assert_same_points([wires], out)
    assert_valid_hierarchy(out)
    assert len({n.key.level for n in nodes_of(out)}) >= 3
    two = convert(tmp_path, SAMPLE, shared_file("extrabytes.las"), name="two.copc.laz", capsys=capsys)
    assert_same_points([SAMPLE, shared_file("extrabytes.las")], two)


def test_level_queries_are_even_samples(tmp_path, capsys):
    """Each level holds a point per occupied cell of its grid at most (the octree by
    spacing): no two points of a level closer than its cells, counted by laspy."""
    out = convert(tmp_path, SAMPLE, capsys=capsys)
    with laspy.CopcReader.open(out) as reader:
        info = reader.copc_info
        root = reader.query(level=0)
        lo = info.center - info.halfsize
        cells = np.floor((np.stack([root.x, root.y, root.z], axis=1) - lo) / info.spacing).astype(np.int64)
    assert np.unique(cells, axis=0).shape[0] == len(root)       # one point a cell
    assert len(root) < laspy.open(out).header.point_count


def node_points(path) -> dict:
    """Each node of the file (level, x, y, z) and its point records, sorted as bytes."""
    with laspy.CopcReader.open(path) as reader:
        nodes = load_octree_for_query(reader.source, reader.copc_info, reader.root_page)
        out = {}
        for node in nodes:
            records = reader._fetch_and_decompress_points_of_nodes([node]).array
            out[(node.key.level, node.key.x, node.key.y, node.key.z)] = np.sort(
                records.view(f"V{records.itemsize}").ravel())
    return out


@pytest.mark.parametrize("leaf", [100_000, 2_000, 150])
def test_out_of_core_equals_in_memory_node_for_node(tmp_path, monkeypatch, leaf):
    """A cloud over memory_points is built a cube at a time from a spill in a scratch
    folder: the same nodes, each with the same points, as the octree built in memory
    (smaller leaves: subtrees below the cubes, and upper nodes that keep every point);
    a valid hierarchy laspy reads whole; the scratch folder left empty."""
    monkeypatch.setattr(copc_write, "LEAF_POINTS", leaf)
    built = {}
    for limit in (None, 20_000):
        out = tmp_path / f"{limit}.copc.laz"
        scratch = tmp_path / f"scratch-{limit}"
        scratch.mkdir()
        with open(out, "w+b") as f:
            written = copc_write.write_copc(f, [str(SAMPLE)], memory_points=limit, scratch=scratch)
        assert list(scratch.iterdir()) == []
        assert_valid_hierarchy(out)
        assert_same_points([SAMPLE], out)
        built[limit] = node_points(out), written
    (whole, a), (cubes, b) = built[None], built[20_000]
    assert whole.keys() == cubes.keys() and (a.nodes, a.levels) == (b.nodes, b.levels)
    assert a.levels > (copc_write.TOP_DEPTH if leaf < 1_000 else 1)
    for key, points in whole.items():
        assert np.array_equal(points, cubes[key]), key


def test_convert_out_of_core_from_the_cli(tmp_path, capsys, monkeypatch):
    """convert builds a cloud over MEMORY_POINTS out of core, its scratch folder beside the
    output: every point of both inputs back, nothing else left; a damaged input fails
    in one line with nothing left either."""
    monkeypatch.setattr(copc_write, "MEMORY_POINTS", 30_000)
    copy = tmp_path / "copy.las"
    shutil.copy(SAMPLE, copy)
    out = convert(tmp_path, SAMPLE, copy, capsys=capsys)
    assert_same_points([SAMPLE, copy], out)
    assert_valid_hierarchy(out)
    assert sorted(os.listdir(tmp_path)) == ["copy.las", "out.copc.laz"]
    data = SAMPLE.read_bytes()
    copy.write_bytes(data[: len(data) * 2 // 3])
    assert "copy.las" in bad_convert(tmp_path, capsys, SAMPLE, copy, tmp_path / "cut.copc.laz")


def bad_convert(tmp_path, capsys, *args) -> str:
    before = set(os.listdir(tmp_path))
    code = main(["convert", *map(str, args)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and err.startswith("progressive: error: "), err
    assert set(os.listdir(tmp_path)) == before          # nothing written, no temporary left
    return err


def test_convert_bad_input(tmp_path, capsys):
    out = tmp_path / "out.copc.laz"
    e57 = BUNNY
    assert "COPC is written from LAS/LAZ" in bad_convert(tmp_path, capsys, SAMPLE, e57, out)
    cut = tmp_path / "cut.laz"
    data = shared_file("TO_core_last_zoom.laz").read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    bad_convert(tmp_path, capsys, cut, out)
    assert "--attribute" in bad_convert(tmp_path, capsys, SAMPLE, out, "--attribute", "intensity")
    assert "missing.las" in bad_convert(tmp_path, capsys, tmp_path / "missing.las", out)
    mine = convert(tmp_path, SAMPLE, name="mine.copc.laz", capsys=capsys)
    assert "is the input" in bad_convert(tmp_path, capsys, mine, mine)


def test_hierarchy_equals_laspy(tmp_path):
    """Every node of the real COPC files (from PDAL and Potree) as laspy walks them."""
    for name in ("lone-star.copc.laz", "lion_takanawa.copc.laz"):
        path = shared_file(name)
        source = open_copc(path)
        mine = {(int(e["level"]), int(e["x"]), int(e["y"]), int(e["z"])): (int(e["offset"]), int(e["byte_size"]),
                int(e["point_count"])) for e in source.hierarchy.nodes}
        theirs = {(n.key.level, n.key.x, n.key.y, n.key.z): (n.offset, n.byte_size, n.point_count)
                  for n in nodes_of(path) if n.point_count > 0}
        assert mine == theirs
        per_level = source.hierarchy.per_level()
        for d, (count, points) in enumerate(per_level):
            with laspy.CopcReader.open(path) as reader:
                assert len(reader.query(level=d)) == points
            assert count == sum(1 for k in theirs if k[0] == d)


def level_cases():
    cases = [("sample", None)]
    for name in ("lone-star.copc.laz", "lion_takanawa.copc.laz"):
        cases.append((name, name))
    return cases


@pytest.fixture(scope="module")
def sample_copc(tmp_path_factory):
    out = tmp_path_factory.mktemp("copc") / "sample.copc.laz"
    assert main(["convert", str(SAMPLE), str(out)]) == 0
    return out


def copc_path(case, sample_copc):
    return sample_copc if case is None else shared_file(case)


@pytest.mark.parametrize("case", [c for _, c in level_cases()])
def test_budget_keeps_whole_levels(case, sample_copc):
    """For a budget between two levels' totals, the loader holds exactly the points of
    levels 0..d, those of laspy's level query in the same (file) order, and each cloud
    index maps back to its point in the file."""
    path = copc_path(case, sample_copc)
    source = open_copc(path)
    levels = source.hierarchy.per_level()
    assert len(levels) >= 2
    full = laspy.read(path)
    xyz = np.stack([full.x, full.y, full.z], axis=1)
    for depth in range(len(levels) - 1):
        kept = sum(p for _, p in levels[: depth + 1])
        budget = kept + levels[depth + 1][1] - 1          # one point short of the next level
        with CloudLoader([path], point_budget=budget) as loader:
            info = loader.info
            batches = sorted(loader, key=lambda b: b.start)
            warnings = loader.warnings
        assert info.points == kept and sum(b.count for b in batches) == kept
        assert any(f"levels 0-{depth} of 0-{len(levels) - 1}" in w for w in warnings)
        with laspy.CopcReader.open(path) as reader:
            expect = reader.query(level=range(0, depth + 1))
        positions = np.concatenate([b.positions for b in batches])
        want = (np.stack([expect.x, expect.y, expect.z], axis=1) - info.origin).astype(np.float32)
        np.testing.assert_array_equal(positions, want)
        index = np.array([info.files[0].file_index(i) for i in range(kept)])
        np.testing.assert_array_equal(xyz[index], np.stack([expect.x, expect.y, expect.z], axis=1))
    with CloudLoader([path], point_budget=len(full.points)) as loader:
        assert loader.info.points == len(full.points) and not loader.info.files[0].runs and not loader.warnings


def test_budget_below_the_root_keeps_the_root(sample_copc):
    source = open_copc(sample_copc)
    (cut,) = keep_levels((source,), 10)
    assert cut.info.points == source.hierarchy.per_level()[0][1] and cut.depth == 0


def plain_copy(path, tmp_path):
    """The file with its COPC info VLR renamed: the same bytes read as plain LAZ."""
    data = bytearray(path.read_bytes())
    assert data[375 + 2:375 + 6] == b"copc"
    data[375 + 2:375 + 6] = b"cop_"
    out = tmp_path / "plain.laz"
    out.write_bytes(bytes(data))
    assert not is_copc(out)
    return out


@pytest.mark.parametrize("case", [None, "lone-star.copc.laz"])
def test_no_limit_ids_equal_plain_laz(case, sample_copc, tmp_path, capsys):
    path = copc_path(case, sample_copc)
    ids = []
    for p in (path, plain_copy(path, tmp_path)):
        out = tmp_path / f"{p.name}.npy"
        assert main(["render", *SMALL, str(p), "--ids", str(out), "--color-by", "intensity"]) == 0, \
            capsys.readouterr().err
        ids.append(np.load(out))
    np.testing.assert_array_equal(ids[0], ids[1])
    assert (ids[0] != 0xFFFFFFFF).sum() > 1000


def kept_file_indices(path, cut) -> np.ndarray:
    """File-order indices of the points of the nodes a cut keeps, in the order the cloud
    holds them (laspy's hierarchy, nodes by their offset in the file)."""
    kept = cut.hierarchy.nodes[cut.kept_nodes()]
    wanted = {(int(e["level"]), int(e["x"]), int(e["y"]), int(e["z"])) for e in kept}
    theirs = sorted((n for n in nodes_of(path) if n.point_count > 0), key=lambda n: n.offset)
    firsts = np.cumsum([0] + [n.point_count for n in theirs])
    return np.concatenate([np.arange(firsts[i], firsts[i + 1]) for i, n in enumerate(theirs)
                           if (n.key.level, n.key.x, n.key.y, n.key.z) in wanted])


@pytest.mark.parametrize("view", ["auto", "close-up"])
@pytest.mark.parametrize("case", [None, "lone-star.copc.laz"])
def test_limit_renders_the_nodes_its_view_needs_exactly(case, view, sample_copc, tmp_path, capsys):
    """Under a limit between levels, render keeps the nodes its camera needs most (the
    auto camera's, or --camera's): the warning, every kept point on the GPU (no random
    subset), the kept nodes those keep_levels chooses for that view, ids equal to the
    float64 reference over laspy's points of those nodes, and a pick reading its point
    back from the file."""
    from progressive.camera import auto_camera
    from progressive.session import node_view

    path = copc_path(case, sample_copc)
    levels = open_copc(path).hierarchy.per_level()
    depth = len(levels) - 2
    budget = sum(p for _, p in levels[: depth + 1]) + levels[depth + 1][1] // 2
    limit = str(limit_for(budget))
    ids_path, stats, cam_path = tmp_path / "ids.npy", tmp_path / "s.json", tmp_path / "c.json"
    camera = close_up(path)[0] if view == "close-up" else None
    given = ["--camera", json.dumps(camera.to_dict())] if camera else []
    code = main(["render", *SMALL, str(path), "--gpu-memory-limit", limit, "--ids", str(ids_path), *given,
                 "--stats", str(stats), "--save-camera", str(cam_path), "--color-by", "intensity"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "octree nodes the view needs most" in err and "uniform random subset" not in err
    assert err.startswith("progressive: warning:")
    cam = Camera.from_json(cam_path.read_text())
    header = laspy.open(path).header
    chosen = cam if camera else auto_camera(np.asarray(header.mins), np.asarray(header.maxs), W / H)
    (cut,) = keep_levels((open_copc(path),), budget, node_view(chosen, W, H))
    index = kept_file_indices(path, cut)
    s = json.loads(stats.read_text())
    assert s["points"] == s["points_on_gpu"] == index.size <= budget
    if camera:
        assert int(cut.hierarchy.nodes[cut.kept_nodes()]["level"].max()) > depth   # deeper than the level cut
    full = laspy.read(path)
    xyz = np.stack([full.x, full.y, full.z], axis=1)[index]
    slots = Permutation.for_count(index.size, order=LAYOUT).forward(np.arange(index.size)).astype(np.int64)
    ids = np.load(ids_path)
    assert np.mean(ids == subset_reference_ids(xyz, np.arange(index.size), cam, W, H, slots)) >= 0.999
    assert (ids != 0xFFFFFFFF).sum() > 300
    shown = np.argwhere(ids != 0xFFFFFFFF)
    row, col = shown[len(shown) // 2]
    code = main(["render", *SMALL, str(path), "--gpu-memory-limit", limit, "--camera", str(cam_path),
                 "--pick", f"{col},{row}", "--color-by", "intensity"])
    out = capsys.readouterr().out
    picked = json.loads(out)
    cloud_index = picked["cloud_index"]
    assert picked["found"] and cloud_index == ids[row, col] and cloud_index < index.size
    assert (picked["x"], picked["y"], picked["z"]) == pytest.approx(tuple(xyz[cloud_index]), abs=1e-6)
    assert picked["index"] == index[cloud_index]


def test_info_reports_the_hierarchy(sample_copc, capsys):
    levels = [(len([n for n in nodes_of(sample_copc) if n.key.level == d]),
               sum(n.point_count for n in nodes_of(sample_copc) if n.key.level == d))
              for d in range(max(n.key.level for n in nodes_of(sample_copc)) + 1)]
    assert main(["info", "--json", str(sample_copc), str(SAMPLE)]) == 0
    desc = json.loads(capsys.readouterr().out)
    copc, plain = desc["files"][0]["copc"], desc["files"][1]["copc"]
    assert plain is None and copc["levels"] == len(levels) and copc["nodes"] == sum(n for n, _ in levels)
    assert [(r["nodes"], r["points"]) for r in copc["per_level"]] == levels
    assert main(["info", str(sample_copc)]) == 0
    text = capsys.readouterr().out
    assert f"COPC hierarchy of {sample_copc}: {len(levels)} levels" in text
    for d, (n, p) in enumerate(levels):
        assert f"  {d:<7}{n:>10,}{p:>14,}" in text


def test_damaged_hierarchy_is_read_as_plain_laz(sample_copc, tmp_path, capsys):
    """A hierarchy whose counts disagree with the header: a warning, every point loaded
    (a limit then falls back to the uniform subset); info names the problem."""
    data = bytearray(sample_copc.read_bytes())
    with laspy.CopcReader.open(sample_copc) as reader:
        at = reader.copc_info.hierarchy_root_offset
    count_at = at + ENTRY.fields["point_count"][1]
    (count,) = struct.unpack_from("<i", data, count_at)
    struct.pack_into("<i", data, count_at, count + 1)
    bad = tmp_path / "bad.copc.laz"
    bad.write_bytes(bytes(data))
    source = open_copc(bad)
    assert source.hierarchy is None and "holds" in source.problem
    with CloudLoader([bad], point_budget=1000) as loader:
        assert loader.info.points == laspy.open(SAMPLE).header.point_count
        assert any("read as plain LAS/LAZ" in w for w in loader.warnings)
    assert main(["info", "--json", str(bad)]) == 0
    assert "holds" in json.loads(capsys.readouterr().out)["files"][0]["copc"]["error"]


def test_copc_written_root_first(sample_copc):
    """convert writes nodes level by level, so a level-limited read is one run of the file."""
    source = open_copc(sample_copc)
    (cut,) = keep_levels((source,), source.hierarchy.per_level()[0][1])
    assert cut.info.runs == ((0, cut.info.points),)
    shutil.copy(sample_copc, sample_copc.with_name("copy.laz"))
    assert is_copc(sample_copc.with_name("copy.laz"))        # told by content, not by name


def test_points_read_back_from_variable_size_chunks():
    """A pick reads its point back from the file: in a COPC file (chunks of variable size,
    where laspy's seek lands on other points) every probed index gives laspy's point."""
    from progressive.loaders import open_cloud
    from progressive.loaders.lookup import read_record

    path = shared_file("lone-star.copc.laz")
    info, full = open_cloud([path]), laspy.read(path)
    for index in map(int, np.linspace(0, len(full.points) - 1, 9)):
        record = read_record(info, int(index))
        assert record["index"] == index and record["attributes"]["intensity"] == full.intensity[index]
        assert (record["x"], record["y"], record["z"]) == pytest.approx(
            (full.x[index], full.y[index], full.z[index]), abs=1e-6)


def test_budget_over_several_files(sample_copc):
    """A COPC file beside a plain one: the plain file is kept whole, the COPC file cut to
    the levels that fit beside it, and cloud indices past the cut file map to the plain
    file's own points."""
    from progressive.loaders.lookup import locate

    plain = laspy.open(SAMPLE).header.point_count
    root = open_copc(sample_copc).hierarchy.per_level()[0][1]
    with CloudLoader([sample_copc, SAMPLE], point_budget=plain + root) as loader:
        info = loader.info
        batches = sorted(loader, key=lambda b: b.start)
    assert [f.points for f in info.files] == [root, plain] and info.points == root + plain
    assert sum(b.count for b in batches) == root + plain
    file, index = locate(info, root + 5)
    assert file.path == str(SAMPLE) and index == 5
    last = (np.concatenate([b.positions for b in batches])[root:] + info.origin).astype(np.float64)
    sample = laspy.read(SAMPLE)
    np.testing.assert_allclose(last, np.stack([sample.x, sample.y, sample.z], axis=1), atol=1e-2)


def test_budget_over_one_copc_file_twice(sample_copc):
    """The same COPC file given twice (sources equal field by field, arrays included) is
    cut to the same levels in both places, each its own source."""
    levels = open_copc(sample_copc).hierarchy.per_level()
    root = levels[0][1]
    with CloudLoader([sample_copc, sample_copc], point_budget=2 * root) as loader:
        info = loader.info
        count = sum(b.count for b in loader)
    assert [f.points for f in info.files] == [root, root] and info.points == count == 2 * root


def test_stats_and_panel_report_levels_nodes_points_and_bytes(tmp_path, capsys):
    """--stats "copc" per file against laspy's hierarchy walk: levels, nodes and points
    kept (under a limit, the nodes the auto camera needs most: keep_levels' choice) of
    the file's, the nodes read and their compressed bytes; null for a plain file. The
    panel's lines say the same."""
    from progressive.camera import auto_camera
    from progressive.loaders.copc import CopcStatus
    from progressive.session import node_view
    from progressive.viewer.status import copc_lines

    path = shared_file("lone-star.copc.laz")
    theirs = [n for n in nodes_of(path) if n.point_count > 0]
    levels = max(n.key.level for n in theirs) + 1
    total = laspy.open(path).header.point_count
    with laspy.CopcReader.open(path) as reader:
        per_level = [len(reader.query(level=d)) for d in range(levels)]
    header = laspy.open(path).header
    for cut, files in ((False, [path, SAMPLE]), (True, [path])):
        kept = theirs
        budget = sum(per_level[:-1]) + per_level[-1] // 2
        if cut:
            view = node_view(auto_camera(np.asarray(header.mins), np.asarray(header.maxs), W / H), W, H)
            (chosen,) = keep_levels((open_copc(path),), budget, view)
            keys = {tuple(int(e[k]) for k in ("level", "x", "y", "z")) for e in chosen.hierarchy.nodes[chosen.kept_nodes()]}
            kept = [n for n in theirs if (n.key.level, n.key.x, n.key.y, n.key.z) in keys]
        depth = max(n.key.level for n in kept)
        points = sum(n.point_count for n in kept)
        limit = ["--gpu-memory-limit", str(limit_for(budget))] if cut else []
        stats = tmp_path / f"{depth}.json"
        code = main(["render", *SMALL, *map(str, files), *limit, "--stats", str(stats), "--color-by", "intensity"])
        assert code == 0, capsys.readouterr().err
        s = json.loads(stats.read_text())
        assert s["points_loaded"] == points + (len(files) - 1) * laspy.open(SAMPLE).header.point_count
        assert s["copc"][0] == {"levels": levels, "levels_kept": depth + 1, "nodes": len(theirs),
                                "nodes_kept": len(kept), "points": total, "points_kept": points,
                                "nodes_read": len(kept), "points_read": points,
                                "bytes_read": sum(n.byte_size for n in kept), "nodes_skipped": 0, "points_skipped": 0,
                                "bytes_fetched": 0, "requests": 0, "requests_in_flight": 0}
        assert s["copc"][1:] == [None] * (len(files) - 1)
        lines = copc_lines(CopcStatus(**s["copc"][0]))
        assert lines[0].strip() == f"COPC levels {depth + 1} / {levels}, nodes {len(kept):,} / {len(theirs):,}"
        assert f"points {points:,} / {total:,} kept" in lines[1]
        assert f"{sum(n.byte_size for n in kept) / 2**20:,.1f} MiB" in lines[2] and len(lines) == 3


def damaged_copc(tmp_path):
    """lone-star with the chunk of one node (the last but one in the file: nodes follow
    it) corrupted in the middle, and that node as laspy's hierarchy gives it."""
    path = shared_file("lone-star.copc.laz")
    node = sorted((n for n in nodes_of(path) if n.point_count > 0), key=lambda n: n.offset)[-2]
    data = bytearray(path.read_bytes())
    middle = node.offset + node.byte_size // 3
    data[middle:middle + 64] = bytes(b ^ 0xFF for b in data[middle:middle + 64])
    bad = tmp_path / "damaged.copc.laz"
    bad.write_bytes(bytes(data))
    return path, bad, node


def test_damaged_node_is_one_line_or_skipped_with_partial(tmp_path, capsys):
    """Without --partial: one line naming the node, exit 2, nothing written. With it: one
    warning naming the node, its points not loaded, every other point at its own index
    (laspy's points of the undamaged file), and the status counting the skip."""
    path, bad, node = damaged_copc(tmp_path)
    key = f"level {node.key.level} key ({node.key.x}, {node.key.y}, {node.key.z})"
    out = tmp_path / "ids.npy"
    assert main(["render", *SMALL, str(bad), "--ids", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("progressive: error: ") and key in err, err
    assert not out.exists()

    stats = tmp_path / "s.json"
    assert main(["render", *SMALL, str(bad), "--partial", "--stats", str(stats)]) == 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("progressive: warning: ") and key in err, err
    assert f"{node.point_count:,} points not loaded" in err
    total = laspy.open(path).header.point_count
    s = json.loads(stats.read_text())
    assert s["points"] == total and s["points_loaded"] == total - node.point_count
    copc = s["copc"][0]
    assert (copc["nodes_skipped"], copc["points_skipped"]) == (1, node.point_count)
    assert copc["bytes_read"] == sum(n.byte_size for n in nodes_of(path) if n.point_count > 0)

    full = laspy.read(path)
    first = int(open_copc(path).hierarchy.first[open_copc(path).hierarchy.nodes["offset"] == node.offset][0])
    with CloudLoader([bad], partial=True) as loader:
        batches = sorted(loader, key=lambda b: b.start)
        info, warnings = loader.info, loader.warnings
    assert sum(b.count for b in batches) == total - node.point_count and len(warnings) == 1
    starts = np.concatenate([np.arange(b.start, b.start + b.count) for b in batches])
    expect = np.r_[np.arange(first), np.arange(first + node.point_count, total)]
    np.testing.assert_array_equal(starts, expect)
    positions = np.concatenate([b.positions for b in batches]).astype(np.float64) + info.origin
    np.testing.assert_allclose(positions, np.stack([full.x, full.y, full.z], axis=1)[expect], atol=1e-3)


def close_up(path) -> tuple:
    """A camera inside the cloud's box near its least corner, looking at the centre, and
    the node-choice view of it (the files' coordinates, the image's height)."""
    from progressive.loaders.copc_choice import View

    header = laspy.open(path).header
    lo, hi = np.asarray(header.mins, np.float64), np.asarray(header.maxs, np.float64)
    eye, centre = lo + (hi - lo) * np.array([0.1, 0.1, 0.5]), (lo + hi) / 2
    camera = Camera(tuple(eye.tolist()), tuple(centre.tolist()), fov_y_deg=60.0, near=1e-3,
                    far=float(np.linalg.norm(hi - lo)) * 2)
    return camera, View(camera.position, tuple((centre - eye).tolist()), H, camera.fov_y_deg)


@pytest.mark.parametrize("case", [c for _, c in level_cases()])
def test_view_cubes_equal_laspy(case, sample_copc):
    """The node cubes the choice ranks are laspy's node bounds (VoxelKey.bounds)."""
    from progressive.loaders.copc_choice import Nodes

    path = copc_path(case, sample_copc)
    h = open_copc(path).hierarchy
    nodes = Nodes.of_files([(h.info.center, h.info.halfsize, h.info.spacing, h.nodes)])
    theirs = {(n.key.level, n.key.x, n.key.y, n.key.z): n.bounds for n in nodes_of(path) if n.point_count > 0}
    assert len(theirs) == nodes.level.size
    for i, e in enumerate(h.nodes):
        bounds = theirs[(int(e["level"]), int(e["x"]), int(e["y"]), int(e["z"]))]
        np.testing.assert_allclose(nodes.lo[i], bounds.mins, rtol=0, atol=1e-9)
        np.testing.assert_allclose(nodes.lo[i] + nodes.side[i], bounds.maxs, rtol=0, atol=1e-9)


@pytest.mark.parametrize("case", [c for _, c in level_cases()])
def test_view_keeps_deeper_nodes_near_the_camera(case, sample_copc):
    """A close-up view with room for half the next level: the level cut keeps levels
    0..d, the view's cut a node deeper than d, those nearer the eye than the ones of that
    level left out, within the budget; what is read is laspy's points of the kept nodes
    (laspy's hierarchy, its file order) and each cloud index maps back to its point."""
    path = copc_path(case, sample_copc)
    source = open_copc(path)
    levels = source.hierarchy.per_level()
    depth = len(levels) - 2
    budget = sum(p for _, p in levels[: depth + 1]) + levels[depth + 1][1] // 2
    camera, view = close_up(path)
    (by_level,) = keep_levels((source,), budget)
    (cut,) = keep_levels((source,), budget, view)
    assert by_level.depth == depth
    kept = source.hierarchy.nodes[cut.kept_nodes()]
    assert int(kept["level"].max()) > depth and cut.info.points == int(kept["point_count"].sum()) <= budget
    theirs = sorted((n for n in nodes_of(path) if n.point_count > 0), key=lambda n: n.offset)
    firsts = np.cumsum([0] + [n.point_count for n in theirs])
    eye = np.asarray(camera.position)

    def distance(n):
        return float(np.linalg.norm(np.clip(eye, n.bounds.mins, n.bounds.maxs) - eye))

    wanted = {(int(e["level"]), int(e["x"]), int(e["y"]), int(e["z"])) for e in kept}
    deeper = [n for n in theirs if n.key.level == depth + 1]
    near = [distance(n) for n in deeper if (n.key.level, n.key.x, n.key.y, n.key.z) in wanted]
    far = [distance(n) for n in deeper if (n.key.level, n.key.x, n.key.y, n.key.z) not in wanted]
    assert near and far and max(near) <= min(far)
    index = np.concatenate([np.arange(firsts[i], firsts[i + 1]) for i, n in enumerate(theirs)
                            if (n.key.level, n.key.x, n.key.y, n.key.z) in wanted])
    full = laspy.read(path)
    xyz = np.stack([full.x, full.y, full.z], axis=1)
    records = np.concatenate(list(cut.chunks(1 << 16)))
    read = np.stack([cut.records.coordinates(records, axis) for axis in range(3)], axis=1)
    np.testing.assert_array_equal(read, xyz[index])
    np.testing.assert_array_equal([cut.info.file_index(i) for i in range(index.size)], index)
    status = cut.info.status()
    assert (status.levels_kept, status.nodes_kept, status.points_kept) == (int(kept["level"].max()) + 1,
                                                                           len(wanted), index.size)
    assert (status.levels, status.nodes, status.points) == (len(levels), len(theirs), len(full.points))
    assert any(f"{len(wanted)} of {len(theirs)} octree nodes the view needs most" in w for w in cut.warnings)
    corners = []
    (again,) = keep_levels((open_copc(path),), budget, lambda lo, hi: corners.append((lo, hi)) or view)
    assert again.chosen == cut.chosen
    np.testing.assert_array_equal(np.concatenate(corners), [full.header.mins, full.header.maxs])


def test_view_budget_over_several_files(sample_copc):
    """A view's cut beside a plain file (kept whole, its points counted against the
    budget) and over one COPC file twice (each its own source; equal nodes tie to the
    first): within the budget, every root kept, the first copy a superset of the second."""
    plain = laspy.open(SAMPLE).header.point_count
    levels = open_copc(sample_copc).hierarchy.per_level()
    room = levels[0][1] + levels[1][1] // 2
    _, view = close_up(sample_copc)
    copc, other = keep_levels((open_copc(sample_copc), open_las(SAMPLE)), plain + room, view)
    assert other.info.points == plain and 0 < copc.info.points <= room and copc.info.levels_kept >= 2
    first, second = keep_levels((open_copc(sample_copc), open_copc(sample_copc)), 2 * levels[0][1] + room, view)
    assert first.info.points + second.info.points <= 2 * levels[0][1] + room
    assert {0} <= set(first.hierarchy.nodes["level"][list(second.chosen)].tolist())
    assert set(second.chosen) < set(first.chosen)


def test_view_without_a_spacing_cuts_by_level(sample_copc):
    """A file whose info VLR has no usable spacing (NaN): every node ties, so the view's
    cut is the level cut's levels and a part of the next level, nothing deeper."""
    source = open_copc(sample_copc)
    info = dataclasses.replace(source.hierarchy.info, spacing=float("nan"))
    source = dataclasses.replace(source, hierarchy=dataclasses.replace(source.hierarchy, info=info))
    levels = source.hierarchy.per_level()
    budget = levels[0][1] + levels[1][1] // 2
    _, view = close_up(sample_copc)
    (cut,) = keep_levels((source,), budget, view)
    kept = source.hierarchy.nodes["level"][cut.kept_nodes()]
    assert np.count_nonzero(kept == 0) == levels[0][0] and 0 < np.count_nonzero(kept == 1) < levels[1][0]
    assert kept.max() == 1 and cut.info.points <= budget
