"""COPC over HTTP: view, render and info on an http:// URL read by range requests from a
server on 127.0.0.1 (tests/range_server.py), against the same file read locally (itself
tested against laspy in test_copc.py) and against what the server counted; and the bad
networks (ranges ignored, connections dropped, a slow server, nothing there), each
within a bound on its time."""

from __future__ import annotations

import dataclasses
import json
import socket
import threading
import time

import laspy
import numpy as np
import pytest
from PIL import Image
from range_server import Faults, RangeServer, self_signed
from test_copc import SMALL, damaged_copc, limit_for, nodes_of, plain_copy

from conftest import SAMPLE, SHARED_DATA, bounded, shared_file
from progressive.cli import main
from progressive.errors import InputError
from progressive.loaders import CloudLoader
from progressive.loaders.copc import open_copc, open_copc_url
from progressive.loaders.http import READ_AHEAD, HttpOptions

COPC_FILES = ("lone-star.copc.laz", "lion_takanawa.copc.laz")
BOUND_S = 30.0
"""Longest any one load, render or failure here may take on a slow machine (llvmpipe, 2
cores); a hang fails the test instead of stalling the suite."""
SHORT_TIMEOUT = HttpOptions(timeout_s=0.5)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Name -> local path of every COPC file served: the sample converted, and the real
    COPC files of ../shared/data that are there."""
    sample = tmp_path_factory.mktemp("http") / "sample.copc.laz"
    assert main(["convert", str(SAMPLE), str(sample)]) == 0
    found = {name: SHARED_DATA / name for name in COPC_FILES if (SHARED_DATA / name).is_file()}
    return {"sample.copc.laz": sample, "plain.las": SAMPLE, **found}


@pytest.fixture(scope="module")
def six_samples(tmp_path_factory):
    """The sample six times over as one COPC file (660,000 points, 27 nodes): opening it
    fetches the nodes of its first BATCH_POINTS points (the colour probe's), which hold
    all of the sample's, and loading it fetches the rest."""
    out = tmp_path_factory.mktemp("http") / "six.copc.laz"
    assert main(["convert", *[str(SAMPLE)] * 6, str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def served(files):
    with RangeServer(files) as server:
        yield server


@pytest.fixture
def server(served):
    """The module's server with its counts reset and no faults."""
    served.faults = Faults()
    served.reset()
    yield served
    served.faults = Faults()


def copc_names():
    return ["sample.copc.laz", *(n for n in COPC_FILES if (SHARED_DATA / n).is_file())]


def run_cli(args, capsys, seconds: float = BOUND_S):
    """(exit status, stdout, stderr, seconds) of the CLI, within `seconds`."""
    code, took = bounded(lambda: main(args), seconds)
    captured = capsys.readouterr()
    return code, captured.out, captured.err, took


def batches_of(path, **kwargs):
    with CloudLoader([path], **kwargs) as loader:
        batches = sorted(loader, key=lambda b: b.start)
        return loader.info, batches, loader.warnings


@pytest.mark.parametrize("name", copc_names())
def test_url_source_equals_the_local_file(name, server, files):
    """Opened by URL, a COPC file gives the local file's source (header facts, attributes,
    hierarchy, decoder layout) but for its path; loaded, the same batches, with no limit
    and cut to whole levels under one."""
    url = server.url(name)
    remote, local = open_copc_url(url), open_copc(files[name])
    skip = {"path", "reads", "fetches", "remote"}
    for f in dataclasses.fields(local.info):
        if f.name not in skip:
            assert getattr(remote.info, f.name) == getattr(local.info, f.name), f.name
    for f in ("attributes", "columns", "first_gps_time", "laz", "depth", "problem"):
        assert getattr(remote, f) == getattr(local, f), f
    assert [w.replace(url, "FILE") for w in remote.warnings] == [w.replace(str(files[name]), "FILE")
                                                                 for w in local.warnings]
    assert remote.records.dtype == local.records.dtype and remote.records.point_data == local.records.point_data
    np.testing.assert_array_equal(remote.hierarchy.nodes, local.hierarchy.nodes)
    np.testing.assert_array_equal(remote.hierarchy.first, local.hierarchy.first)
    levels = local.hierarchy.per_level()
    for budget in (None, sum(p for _, p in levels[:-1])):
        (info, mine, _), _ = bounded(lambda b=budget: batches_of(url, point_budget=b), BOUND_S)
        theirs_info, theirs, _ = batches_of(files[name], point_budget=budget)
        assert info.points == theirs_info.points and info.files[0].runs == theirs_info.files[0].runs
        assert [b.start for b in mine] == [b.start for b in theirs]
        for a, b in zip(mine, theirs, strict=True):
            np.testing.assert_array_equal(a.positions, b.positions)
            assert a.attributes.keys() == b.attributes.keys()
            for key in a.attributes:
                np.testing.assert_array_equal(a.attributes[key], b.attributes[key])


@pytest.mark.parametrize("name", ["sample.copc.laz", "lone-star.copc.laz"])
def test_render_over_http_equals_local_and_plain_laz(name, server, files, tmp_path, capsys):
    """render --ids of the URL equals the local file's and, with no limit, the same bytes
    read as plain LAZ; under a limit, the local file's cut to the same levels."""
    if not files.get(name):
        pytest.skip(f"{name} not available")
    levels = open_copc(files[name]).hierarchy.per_level()
    cut = ["--gpu-memory-limit", str(limit_for(sum(p for _, p in levels[:-1]) + levels[-1][1] // 2))]
    for limit in ([], cut):
        ids = []
        for source in (server.url(name), str(files[name]), *([] if limit else [str(plain_copy(files[name], tmp_path))])):
            out = tmp_path / "ids.npy"
            code, _, err, _ = run_cli(["render", *SMALL, source, *limit, "--ids", str(out), "--color-by", "intensity"],
                                      capsys)
            assert code == 0, err
            ids.append(np.load(out))
        for other in ids[1:]:
            np.testing.assert_array_equal(ids[0], other)
        assert (ids[0] != 0xFFFFFFFF).sum() > 500


def test_stats_count_what_the_server_sent(server, files, tmp_path, capsys):
    """--stats "copc" of a URL: bytes fetched and requests answered as the server counted
    them, none in flight at the end, no range fetched twice (the nodes read while opening
    the file are kept for the first image); the kept nodes read with their chunks' bytes
    as laspy's hierarchy gives them; the panel's line says what was fetched."""
    from progressive.loaders.copc import CopcStatus
    from progressive.viewer.status import copc_lines

    name = "lone-star.copc.laz" if "lone-star.copc.laz" in files else "sample.copc.laz"
    theirs = [n for n in nodes_of(files[name]) if n.point_count > 0]
    stats = tmp_path / "s.json"
    code, _, err, _ = run_cli(["render", *SMALL, server.url(name), "--stats", str(stats)], capsys)
    assert code == 0, err
    copc = json.loads(stats.read_text())["copc"][0]
    requests, sent = server.counts()
    assert (copc["bytes_fetched"], copc["requests"], copc["requests_in_flight"]) == (sent, requests, 0)
    assert copc["nodes_read"] == len(theirs) and copc["bytes_read"] == sum(n.byte_size for n in theirs)
    assert copc["bytes_read"] < copc["bytes_fetched"] <= files[name].stat().st_size + READ_AHEAD    # header read-ahead
    assert len(set(server.ranges)) == len(server.ranges)        # nothing fetched twice
    lines = copc_lines(CopcStatus(**copc))
    assert lines[3] == f"    fetched {sent / 2**20:,.1f} MiB in {requests:,} requests, 0 in flight"
    assert len(lines) == 4


def test_requests_in_flight_are_bounded(files, six_samples):
    """Nodes are fetched a few at a time: with every node's answer slowed, the server (one
    of this test's own) holds exactly `in_flight` requests at once while the cloud loads,
    never more, and the status (and the panel's line) says so while it does (the answers
    are held until the status is read: on a slow machine the first could otherwise come
    back before). The file's load must fetch more nodes than that, beyond those opening it
    fetched: the sample alone is fetched whole by then (where ../shared/data is absent)."""
    from progressive.viewer.status import copc_lines

    name, path = ("lone-star.copc.laz", files["lone-star.copc.laz"]) if "lone-star.copc.laz" in files else \
        ("six.copc.laz", six_samples)
    nodes = open_copc(path).hierarchy.nodes
    in_flight = 3
    with RangeServer({name: path}) as own:
        loader = CloudLoader([own.url(name)], http=HttpOptions(in_flight=in_flight))
        own.faults.delays = {int(offset): 0.2 for offset in nodes["offset"]}
        own.faults.hold = held = threading.Event()
        with loader:
            assert nodes.size - len(loader.sources[0].held) > in_flight, "the load should fetch more nodes than that"
            own.reset()
            loader.start()
            try:
                deadline = time.monotonic() + BOUND_S
                while own.active < in_flight and time.monotonic() < deadline:
                    time.sleep(0.005)
                seen = loader.info.files[0].status()
            finally:
                held.set()
            count = sum(b.count for b in loader)
        assert count == loader.info.points
        assert own.most_active == in_flight and seen.requests_in_flight == in_flight
        assert copc_lines(seen)[3].endswith(f" requests, {in_flight} in flight")     # the panel's
        assert loader.info.files[0].status().requests_in_flight == 0


def test_connections_are_kept_alive(files):
    """Requests reuse their connections (one per request in flight at most); a server that
    closes them after each answer costs a new connection each, not a retry or a node."""
    name = "lone-star.copc.laz" if "lone-star.copc.laz" in files else "sample.copc.laz"
    options = HttpOptions(in_flight=2)
    for close_idle in (False, True):
        with RangeServer({name: files[name]}) as own:
            own.faults.close_idle = close_idle
            (info, batches, warnings), _ = bounded(lambda: batches_of(own.url(name), http=options), BOUND_S)
            status = info.files[0].status()
            assert sum(b.count for b in batches) == info.points and not warnings and status.nodes_skipped == 0
            assert (status.requests, status.bytes_fetched) == own.counts()
            if close_idle:
                assert own.connections == status.requests
            else:
                assert own.connections <= options.in_flight < status.requests


@pytest.mark.parametrize("name", ["sample.copc.laz", "lone-star.copc.laz"])
def test_info_over_http_equals_local(name, server, files, capsys):
    """info --json of the URL is the local file's but for the path, CRS keys included:
    pyproj's CRS read from the header fetched again (lone-star's WKT is named "unnamed"
    and carries no EPSG code at its top, so its label alone gives pyproj nothing)."""
    if not files.get(name):
        pytest.skip(f"{name} not available")
    descs = []
    for source in (server.url(name), str(files[name])):
        code, out, err, _ = run_cli(["info", "--json", source], capsys)
        assert code == 0, err
        descs.append(json.loads(out.replace(json.dumps(source)[1:-1], "FILE")))
    assert descs[0] == descs[1]
    assert descs[0]["crs_name"] == laspy.open(files[name]).header.parse_crs().name
    assert descs[0]["files"][0]["copc"]["levels"] == open_copc(files[name]).hierarchy.levels


def test_info_http_timeout(files, capsys):
    """info --http-timeout: a server slower than it to send the header fails within it, one
    line; a bad value is refused as render's is. (A server of the test's own: the slow
    answer, which comes after the test, must not count in another test's.)"""
    with RangeServer({"a.copc.laz": files["sample.copc.laz"]}) as own:
        own.faults.delays = {0: 4.0}
        for extra in ([], ["--reproject", "EPSG:4978"]):
            code, _, err, took = run_cli(["info", own.url("a.copc.laz"), "--http-timeout", "0.5", *extra], capsys)
            assert_one_error(code, err, "no answer", "within 0.5 s")
            assert took < 4.0
        code, _, err, _ = run_cli(["info", own.url("a.copc.laz"), "--http-timeout", "0"], capsys)
        assert_one_error(code, err, "--http-timeout")


def test_the_open_fetches_the_first_nodes_back_to_back(files):
    """The first nodes the open holds for the first image lie back to back in the file
    and come in one range request for each of the probe's two reads (at most
    HELD_RUN_BYTES each), not one a node; each node's bytes are the file's."""
    name = "sample.copc.laz"
    data = files[name].read_bytes()
    with RangeServer({name: files[name]}) as own:
        source = open_copc_url(own.url(name))
        try:
            sizes = {int(n["offset"]): int(n["byte_size"]) for n in source.hierarchy.nodes}
            assert len(source.held) > 2
            for offset, chunk in source.held.items():
                assert len(chunk) == sizes[offset] and chunk == data[offset:offset + sizes[offset]]
            node_ranges = [r for r in own.ranges if r[0] in sizes]
            assert len(node_ranges) <= 2 < len(source.held), node_ranges
        finally:
            source.close()


def test_http_requests_flag(files, tmp_path, capsys):
    """render --http-requests n: up to n range requests at once, and that many while the
    nodes wait for answers that come late (a server of the test's own, whose counts are
    this render's alone); the image that of the default; a bad value refused in one line.
    (lone-star has no colours: the open holds only its first node, so the render fetches
    the others.)"""
    name = "lone-star.copc.laz"
    if name not in files:
        pytest.skip(f"{name} is not in ../shared/data")
    assert open_copc(files[name]).hierarchy.nodes.size > 4, "the render should need more nodes than requests"
    images = {}
    for n in (1, 3):
        with RangeServer({name: files[name]}) as own:
            own.faults.pause = 0.05
            out = tmp_path / f"{n}.png"
            code, _, err, _ = run_cli(["render", *SMALL, own.url(name), "--http-requests", str(n), "--out", str(out)],
                                      capsys)
            assert code == 0, err
            requests, _ = own.counts()
            assert own.most_active == n < requests
            images[n] = np.asarray(Image.open(out))
    np.testing.assert_array_equal(images[1], images[3])
    for bad in ("0", "65", "many"):
        code, _, err, _ = run_cli(["render", *SMALL, files[name].as_uri(), "--http-requests", bad], capsys)
        assert_one_error(code, err, "--http-requests")


def pick_at_centre(capsys, tmp_path, source, *args) -> tuple[dict, np.ndarray]:
    """render --pick at the image's centre: the pick's JSON and the ids image."""
    ids = tmp_path / "pick_ids.npy"
    width, height = int(SMALL[1]), int(SMALL[3])
    code, out, err, _ = run_cli(["render", *SMALL, source, *args, "--ids", str(ids),
                                 f"--pick={width // 2},{height // 2}"], capsys)
    assert code == 0, err
    return json.loads(out), np.load(ids)


@pytest.mark.parametrize("name", copc_names())
def test_pick_over_http_equals_local_and_laspy(name, server, files, tmp_path, capsys):
    """render --pick of the URL gives the local file's pick (every attribute, the CRS and
    latitude and longitude it reads from the header fetched again), all of the point as
    laspy reads it at that file index: with every level, and with the nodes cut (the
    cloud's index may then map to another index of the file)."""
    las = laspy.read(files[name])
    levels = open_copc(files[name]).hierarchy.per_level()
    kept = sum(p for _, p in levels[:-1]) + levels[-1][1] // 2
    for limit in ([], ["--gpu-memory-limit", str(limit_for(kept))]):
        got, ids = pick_at_centre(capsys, tmp_path, server.url(name), *limit)
        theirs, local_ids = pick_at_centre(capsys, tmp_path, str(files[name]), *limit)
        np.testing.assert_array_equal(ids, local_ids)
        assert got["found"] and got["file"] == server.url(name) and theirs["file"] == str(files[name])
        assert {**got, "file": None} == {**theirs, "file": None}
        i = got["index"]
        for axis, scale in zip("xyz", las.header.scales):
            assert abs(got[axis] - float(las[axis][i])) <= scale / 2, axis     # rounded to its decimals
        dims = [d for d in las.point_format.dimension_names if d not in ("X", "Y", "Z")]
        assert sorted(got["attributes"]) == sorted(dims)
        for dim in dims:
            value = np.asarray(las[dim])[i]
            assert np.array_equal(np.asarray(got["attributes"][dim], dtype=value.dtype), value, equal_nan=True), dim


def settled(info, quiet_s: float = 0.3, limit_s: float = 10.0) -> None:
    """Wait until the file's requests have stopped for quiet_s (background fetches done)."""
    deadline, last, since = time.monotonic() + limit_s, None, time.monotonic()
    while time.monotonic() < deadline:
        status = info.files[0].status()
        now = (status.requests, status.requests_in_flight, status.bytes_fetched)
        if now != last:
            last, since = now, time.monotonic()
        elif not status.requests_in_flight and time.monotonic() - since >= quiet_s:
            return
        time.sleep(0.01)


def test_pick_fetches_its_node_once_and_counts_it(server, files):
    """A pick's point is read twice (record and coordinates): its node is fetched once,
    by one range request of its chunk, which the file's status counts; a node whose
    connection drops on every try is one line (InputError) naming the URL."""
    from progressive.loaders import open_cloud
    from progressive.loaders.lookup import read_point, read_record

    name = "lone-star.copc.laz" if "lone-star.copc.laz" in files else "sample.copc.laz"
    info, _ = bounded(lambda: open_cloud([server.url(name)]), BOUND_S)
    nodes = open_copc(files[name]).hierarchy
    k = nodes.nodes.size // 2
    index = int(nodes.first[k]) + 3
    settled(info)       # the nodes fetched ahead for a first image are in before the count starts
    server.reset()
    before = info.files[0].status()
    record, point = read_record(info, index), read_point(info, index)
    node = nodes.nodes[k]
    assert server.ranges == [(int(node["offset"]), int(node["offset"]) + int(node["byte_size"]) - 1)]
    assert [record[a] for a in "xyz"] == pytest.approx(point.tolist(), abs=1e-9)
    after = info.files[0].status()
    assert (after.requests - before.requests, after.bytes_fetched - before.bytes_fetched) == server.counts()
    other = nodes.nodes[k + 1]
    server.faults.drops = {int(other["offset"]): -1}
    with pytest.raises(InputError, match="dropped") as caught:
        read_record(info, int(nodes.first[k + 1]))
    assert "\n" not in str(caught.value) and server.url(name) in str(caught.value)


def assert_one_error(code, err, *phrases):
    assert code == 2 and err.count("\n") == 1 and err.startswith("progressive: error: "), err
    for phrase in phrases:
        assert phrase in err, err


def test_server_that_ignores_ranges(server, tmp_path, capsys):
    server.faults.ignore_ranges = True
    out = tmp_path / "out.png"
    code, _, err, took = run_cli(["render", *SMALL, server.url("sample.copc.laz"), "--out", str(out)], capsys)
    assert_one_error(code, err, "ignores range requests", "200")
    assert not out.exists() and took < BOUND_S


@pytest.fixture(scope="module")
def tls(tmp_path_factory):
    """A self-signed certificate for 127.0.0.1 and its key."""
    return self_signed(tmp_path_factory.mktemp("tls"))


def test_https_equals_local(files, tls, tmp_path, capsys, monkeypatch):
    """Over HTTPS, from a server whose self-signed certificate the client is told to
    trust (SSL_CERT_FILE, as a user with a private CA does), info --json and render
    --ids equal the local file's."""
    monkeypatch.setenv("SSL_CERT_FILE", str(tls[0]))
    local = str(files["sample.copc.laz"])
    with RangeServer(files, tls=tls) as secure:
        url = secure.url("sample.copc.laz")
        assert url.startswith("https://")
        descs, ids = [], []
        for source in (url, local):
            code, out, err, _ = run_cli(["info", "--json", source], capsys)
            assert code == 0, err
            descs.append(json.loads(out.replace(json.dumps(source)[1:-1], "FILE")))
            path = tmp_path / "ids.npy"
            code, _, err, _ = run_cli(["render", *SMALL, source, "--ids", str(path)], capsys)
            assert code == 0, err
            ids.append(np.load(path))
        assert secure.counts()[1] > 0
    assert descs[0] == descs[1]
    np.testing.assert_array_equal(ids[0], ids[1])
    assert (ids[0] != 0xFFFFFFFF).sum() > 500


def test_https_certificate_not_trusted(files, tls, tmp_path, capsys, monkeypatch):
    """A certificate nobody vouches for: one line that says so, exit status 2, nothing
    written, for render and info."""
    monkeypatch.delenv("SSL_CERT_FILE", raising=False)
    out = tmp_path / "out.png"
    with RangeServer(files, tls=tls) as secure:
        url = secure.url("sample.copc.laz")
        code, _, err, _ = run_cli(["render", *SMALL, url, "--out", str(out)], capsys)
        assert_one_error(code, err, url, "certificate verify failed")
        assert not out.exists()
        code, _, err, _ = run_cli(["info", url], capsys)
        assert_one_error(code, err, url, "certificate verify failed")


def test_nothing_there(server, tmp_path, capsys):
    """404, a port nobody listens on, a file that is not COPC: one line each, no output."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        closed = f"http://127.0.0.1:{probe.getsockname()[1]}/x.copc.laz"
    out = tmp_path / "out.png"
    for url, phrase in ((server.url("missing.copc.laz"), "HTTP 404"), (closed, "cannot connect"),
                        (server.url("plain.las"), "is not a COPC file")):
        code, _, err, _ = run_cli(["render", *SMALL, url, "--out", str(out)], capsys)
        assert_one_error(code, err, url, phrase)
        assert not out.exists()
        code, _, err, _ = run_cli(["info", url], capsys)
        assert_one_error(code, err, url, phrase)


@pytest.mark.parametrize("name", ["lone-star.copc.laz", "six.copc.laz"])
def test_connection_dropped_once_is_tried_again(name, files, six_samples, tmp_path, capsys):
    """A node's answer cut in the middle once: fetched again, every point loaded as from
    the local file; the retry is a request the status counts. The node is one the load
    fetches on its own, not one opening the file fetched among the colour probe's (the
    sample alone is fetched whole by then: six of it are not)."""
    path = six_samples if name == "six.copc.laz" else files.get(name)
    if path is None:
        pytest.skip(f"{name} not available")
    node = sorted((n for n in nodes_of(path) if n.point_count > 0), key=lambda n: n.offset)[-2]
    ids, stats = tmp_path / "ids.npy", tmp_path / "s.json"
    with RangeServer({name: path}) as own:
        own.faults.drops = {node.offset: 1}
        code, _, err, _ = run_cli(["render", *SMALL, own.url(name), "--ids", str(ids), "--stats", str(stats)], capsys)
        assert code == 0 and not err, err
        assert own.ranges.count((node.offset, node.offset + node.byte_size - 1)) == 2
        requests, sent = own.counts()
    copc = json.loads(stats.read_text())["copc"][0]
    # what the client counts arrived: at most what the server wrote (bytes written before a
    # connection closes can be lost in flight), and at least every node whole (each one's
    # answer arrived once in full)
    whole = sum(n.byte_size for n in nodes_of(path) if n.point_count > 0)
    assert copc["requests"] == requests and whole <= copc["bytes_fetched"] <= sent and copc["nodes_skipped"] == 0
    local = tmp_path / "local.npy"
    assert main(["render", *SMALL, str(path), "--ids", str(local)]) == 0
    np.testing.assert_array_equal(np.load(ids), np.load(local))


def test_connection_dropped_every_time(server, tmp_path, capsys):
    """A node whose answer is always cut: one line naming it, exit 2, nothing written; with
    --partial one warning naming it and its points, and the image of the local file whose
    same node does not decode (test_copc: every other point at its own index)."""
    path, damaged, node = damaged_copc(tmp_path)
    with RangeServer({"a.copc.laz": path}) as own:
        own.faults.drops = {node.offset: -1}
        url, out = own.url("a.copc.laz"), tmp_path / "ids.npy"
        key = f"level {node.key.level} key ({node.key.x}, {node.key.y}, {node.key.z})"
        code, _, err, _ = run_cli(["render", *SMALL, url, "--ids", str(out)], capsys)
        assert_one_error(code, err, key, "could not be fetched", "dropped")
        assert not out.exists()
        assert own.ranges.count((node.offset, node.offset + node.byte_size - 1)) == 2     # one retry
        stats = tmp_path / "s.json"
        code, _, err, _ = run_cli(["render", *SMALL, url, "--partial", "--ids", str(out), "--stats", str(stats)],
                                  capsys)
        assert code == 0 and err.count("\n") == 1 and err.startswith("progressive: warning: "), err
        assert key in err and f"{node.point_count:,} points not loaded" in err and "dropped" in err
    copc = json.loads(stats.read_text())["copc"][0]
    assert (copc["nodes_skipped"], copc["points_skipped"]) == (1, node.point_count)
    local = tmp_path / "local.npy"
    assert main(["render", *SMALL, str(damaged), "--partial", "--ids", str(local)]) == 0
    np.testing.assert_array_equal(np.load(out), np.load(local))
    total = laspy.open(path).header.point_count
    assert json.loads(stats.read_text())["points_loaded"] == total - node.point_count


def test_slow_server_times_out(server, files, tmp_path, capsys):
    """A server that answers node requests later than the timeout: one line within the
    bound (the loader does not wait for the slow answers still in flight), from the CLI's
    --http-timeout as from HttpOptions; so does a server slow to send the header."""
    name = "sample.copc.laz"
    nodes = open_copc(files[name]).hierarchy.nodes
    delay = 4.0
    server.faults.delays = {int(offset): delay for offset in nodes["offset"][1:]}     # the root: the probe
    out = tmp_path / "out.png"
    code, _, err, took = run_cli(["render", *SMALL, server.url(name), "--http-timeout", "0.5", "--out", str(out)],
                                 capsys)
    assert_one_error(code, err, "no answer", "within 0.5 s")
    assert took < delay and not out.exists()
    for bad in ("0", "-1", "soon"):
        code, _, err, _ = run_cli(["render", *SMALL, server.url(name), "--http-timeout", bad], capsys)
        assert_one_error(code, err, "--http-timeout")
    with pytest.raises(InputError, match="within 0.5 s") as caught:
        bounded(lambda: batches_of(server.url(name), http=SHORT_TIMEOUT), delay)
    assert "\n" not in str(caught.value)
    server.faults.delays = {0: delay}
    began = time.monotonic()
    with pytest.raises(InputError, match="within 0.5 s"):
        bounded(lambda: open_copc_url(server.url(name), http=SHORT_TIMEOUT), delay)
    assert time.monotonic() - began < delay


def test_trickling_server_times_out(server, files):
    """A server that sends a node's bytes one at a time, 20 a second: it never falls
    silent for the timeout, but fails for bringing too little within one (one line)."""
    nodes = open_copc(files["sample.copc.laz"]).hierarchy.nodes
    server.faults.trickle = {int(offset): 0.05 for offset in nodes["offset"][1:]}
    bound = 4 * SHORT_TIMEOUT.timeout_s + 2
    with pytest.raises(InputError, match="too slowly") as caught:
        bounded(lambda: batches_of(server.url("sample.copc.laz"), http=SHORT_TIMEOUT), bound)
    assert "\n" not in str(caught.value)
    assert min(int(n) for n in nodes["byte_size"][1:]) > bound / 0.05       # more than a trickle brings by then


def test_session_survives_a_failed_fetch(server, files, gl, monkeypatch):
    """The viewer's loading path: a node that cannot be fetched fails the frame that pumps
    it with an InputError (the viewer shows it and calls stop_loading); the session then
    keeps drawing the points read before: every task read before the failure, parsed and
    handed over first. The same points whether one parser thread parses them at once or
    a parser thread a node, each parse slowed, is still parsing (or held for the first
    frame) when the last node's fetch fails, as on the H100 machine's 16 cores, where
    the error came before any batch and the viewer kept none."""
    from progressive.loaders.copc import CopcSource
    from progressive.session import Session, SessionOptions

    name = "lone-star.copc.laz"        # no RGB: opening it reads its root node only
    if name not in files:
        pytest.skip(f"{name} not available")
    nodes = open_copc(files[name]).hierarchy.nodes
    assert nodes.size > 2
    server.faults.drops = {int(nodes["offset"][-1]): -1}
    options = SessionOptions(width=160, height=120, http=HttpOptions(timeout_s=5), parser_threads=1)
    real = CopcSource.parse

    def slow(self, *args, **kwargs):
        time.sleep(0.3)
        return real(self, *args, **kwargs)

    loaded = []
    for slowed in (False, True):
        if slowed:
            monkeypatch.setattr(CopcSource, "parse", slow)
            options = dataclasses.replace(options, parser_threads=int(nodes.size))
        began = time.monotonic()            # on this thread: the GL context is current here
        with Session([server.url(name)], options, glc=gl) as s:
            camera = s.auto_camera()
            with pytest.raises(InputError, match="could not be fetched"):
                for _ in range(10_000):
                    s.frame(camera)
            s.stop_loading()
            s.frame(camera)
            loaded.append(s.status().loaded)
            shown = int((s.ids() != 0xFFFFFFFF).sum())
        assert time.monotonic() - began < BOUND_S
        assert shown > 0
    assert 0 < loaded[0] == loaded[1] <= int(nodes["point_count"][:-1].sum()), loaded


def test_streaming_a_url_draws_while_nodes_are_on_their_way():
    """Streamed over HTTP with every node's answer a second late: frames keep coming while
    the nodes are fetched (the frame loop never waits for the network), then the still
    view is exact over the resident nodes, which were each fetched once. lone-star: it
    has no RGB, so opening it fetches only its first node (a file with RGB fetches the
    nodes of its first 500,000 points to decide its colours' bits: all of the sample's).
    A server of its own: another test's late answers cannot land in its counts."""
    from test_copc_stream import assert_exact, assert_tree_cut, las_xyz, resident, streamed

    path = shared_file("lone-star.copc.laz")
    name = path.name
    nodes = [n for n in nodes_of(path) if n.point_count > 0]
    _, xyz = las_xyz(path)
    with RangeServer({name: path}) as server:
        server.faults.delays = {n.offset: 1.0 for n in nodes}

        def run():
            with streamed(server.url(name), limit_for(250_000), color_by="intensity") as s:
                camera = s.auto_camera()
                while_loading = 0
                s.frame(camera)
                while not s.converged:      # bounded() ends a hang
                    while_loading += s.status().stream.loading_nodes > 0
                    s.frame(camera)
                assert_tree_cut(s)
                assert_exact(s, camera, xyz)
                return while_loading, resident(s)[0].size

        (frames, kept), _ = bounded(run, BOUND_S)
        fetched = [r for r in server.ranges if r[0] in server.faults.delays]
    assert frames >= 5
    assert len(fetched) == len(set(fetched)) >= kept - 1     # the first node may come within the first bytes read
