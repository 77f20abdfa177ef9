"""Numerical stability at geospatial scale: the render must not depend on where the
cloud sits, millimetres must survive at UTM/ECEF magnitudes, and depth order must be
right wherever float64 says it is clear."""

from __future__ import annotations

import laspy
import numpy as np
import pytest

from conftest import SAMPLE
from progressive.attributes import default_attribute
from progressive.camera import Camera, auto_camera
from progressive.loaders import CloudLoader
from progressive.loaders.las import _bit_field
from progressive.loaders.types import AttributeInfo, AttributeKind, Batch, CloudInfo, nonfinite_count
from progressive.reference import EMPTY, reference_ids
from progressive.renderer import Raster, Renderer

W, H = 160, 120


def render_file(gl, path, camera, raster=Raster.COMPUTE):
    with CloudLoader([path]) as loader:
        info = loader.info
        r = Renderer(gl, info, default_attribute(info), raster=raster, width=W, height=H)
        loader.start()
        for batch in loader:
            r.add_batch(batch)
    ids = r.render(camera, W, H, r.style()).ids
    r.release()
    return ids, info


def moved_copy(src, dst, shift):
    """The same points in a new LAS whose offset is moved by `shift` (integers untouched)."""
    las = laspy.read(src)
    offsets = np.asarray(las.header.offsets) + shift
    header = laspy.LasHeader(point_format=las.header.point_format, version=las.header.version)
    header.scales = las.header.scales
    header.offsets = offsets
    out = laspy.LasData(header)
    out.points = laspy.ScaleAwarePointRecord(las.points.array.copy(), las.header.point_format,
                                             las.header.scales, offsets)
    out.write(dst)
    return dst


def shifted(camera: Camera, shift) -> Camera:
    return Camera(tuple(np.add(camera.position, shift).tolist()), tuple(np.add(camera.target, shift).tolist()),
                  camera.up, camera.fov_y_deg, camera.near, camera.far)


@pytest.mark.parametrize("raster", [Raster.COMPUTE, Raster.POINTS])
@pytest.mark.parametrize("shift", [(5e6, 5e6, 1e3), (6.4e6, 6.4e6, 6.4e6), (-6.4e6, 3e6, -6.4e6)],
                         ids=["utm", "ecef", "ecef-negative"])
def test_translation_invariance(gl, tmp_path, shift, raster):
    with CloudLoader([SAMPLE]) as loader:
        info = loader.info
    cam = auto_camera(info.bounds_min, info.bounds_max, W / H)
    base, _ = render_file(gl, SAMPLE, cam, raster)
    moved_path = moved_copy(SAMPLE, tmp_path / "moved.las", np.array(shift))
    moved, moved_info = render_file(gl, moved_path, shifted(cam, shift), raster)
    assert np.allclose(moved_info.origin - info.origin, shift, rtol=0, atol=1e-6)
    assert (base != EMPTY).sum() > 1000
    assert np.array_equal(base, moved)


def synthetic(gl, xyz: np.ndarray, raster=Raster.COMPUTE):
    """A Renderer holding float64 points (numeric stress, not real data)."""
    lo, hi = xyz.min(axis=0), xyz.max(axis=0)
    attr = AttributeInfo("elevation", AttributeKind.SCALAR, np.dtype("f8"), float((lo[2] + hi[2]) / 2))
    info = CloudInfo(files=(), points=len(xyz), origin=(lo + hi) / 2, bounds_min=lo, bounds_max=hi, attributes=(attr,))
    r = Renderer(gl, info, attr, raster=raster, width=W, height=H)
    r.add_batch(Batch(start=0, xyz=(xyz - info.origin).astype(np.float32)))
    return r


def test_camera_one_kilometre_from_a_millimetre_patch(gl):
    """A 1 mm grid at UTM coordinates seen from 1 km with pixels of ~0.6 mm: every
    point lands where float64 puts it."""
    g = np.arange(-60, 60) * 0.001
    x, y = np.meshgrid(g, g)
    base = np.array([512_345.678, 5_481_234.567, 312.5])
    xyz = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1) + base
    fov = np.degrees(2 * np.arctan(H * 0.0006 / 2 / 1000.0))
    aim = base + [0.00023, 0.00017, 0.0]     # off the grid, so no column sits exactly on a pixel edge
    cam = Camera(tuple((aim + [0.0, -1000.0 * np.sin(0.3), 1000.0 * np.cos(0.3)]).tolist()), tuple(aim.tolist()),
                 (0.0, 1.0, 0.0), fov, 900.0, 1100.0)
    r = synthetic(gl, xyz)
    got = r.render(cam, W, H, r.style()).ids
    ref = reference_ids(xyz, cam, W, H, tie_key=r.store.slots_of(np.arange(len(xyz))).astype(np.int64))
    assert (ref != EMPTY).sum() > 5000
    assert np.mean(got == ref) >= 0.999
    r.release()


@pytest.mark.parametrize("raster", [Raster.COMPUTE, Raster.POINTS])
@pytest.mark.parametrize("distance", [10.0, 10_000.0])
def test_one_centimetre_apart_resolves_at_any_distance(gl, distance, raster):
    """Two parallel patches 1 cm apart, near = 0.01 m and far = 1e5 m: the nearer one
    wins every pixel. Depth is the float32 view distance itself (relative precision
    2^-24 at any depth), not a perspective z-buffer value."""
    n = 80
    side = distance * 0.2
    g = np.linspace(-side / 2, side / 2, n)
    x, z = np.meshgrid(g, g)
    base = np.array([631_000.25, 4_833_000.75, 80.0])
    front = np.stack([x.ravel(), np.full(x.size, distance), z.ravel()], axis=1) + base
    back = front + [0.0, 0.01, 0.0]
    xyz = np.concatenate([back, front])        # the far patch first in the file
    cam = Camera(tuple(base.tolist()), tuple((base + [0.0, 1.0, 0.0]).tolist()), (0.0, 0.0, 1.0), 20.0, 0.01, 1e5)
    r = synthetic(gl, xyz, raster)
    ids = r.render(cam, W, H, r.style()).ids
    shown = ids[ids != EMPTY]
    assert shown.size > 500
    assert np.all(shown >= len(back)), f"{np.count_nonzero(shown < len(back))} pixels show the farther patch"
    r.release()


def test_nonfinite_values_and_positions_are_never_drawn(gl):
    """A NaN or infinite shown value, or coordinate, is skipped and counted; such a point
    must not hide the point behind it."""
    from progressive.loaders.records import pack_records
    from progressive.loaders.types import nonfinite_records

    n = 6
    xyz = np.array([[0.0, 5.0, 0.0], [0.0, 6.0, 0.0], [0.3, 5.0, 0.0], [0.3, 6.0, 0.0], [-0.3, 5.0, 0.0],
                    [-0.3, 6.0, 0.0]]) + [500_000.0, 5_000_000.0, 10.0]
    values = np.array([np.nan, 1.0, np.inf, 2.0, 3.0, 4.0])
    attr = AttributeInfo("reflectance", AttributeKind.SCALAR, np.dtype("f4"))
    origin = xyz.mean(axis=0)
    positions = (xyz - origin).astype(np.float32)
    positions[4, 0] = np.nan                   # a non-finite coordinate (fast-format style)
    batch = Batch(start=0, xyz=positions, attributes={"reflectance": values}, nonfinite_positions=1,
                  nonfinite_values={"reflectance": 2})      # as a loader counts them
    records = pack_records(batch, attr, float(origin[2]))
    assert nonfinite_records(records)[0] == 3
    info = CloudInfo(files=(), points=n, origin=origin, bounds_min=xyz.min(0), bounds_max=xyz.max(0), attributes=(attr,))
    cam = Camera(tuple((origin + [0.0, -5.0, 0.0]).tolist()), tuple(origin.tolist()), (0.0, 0.0, 1.0), 40.0, 0.1, 100.0)
    for raster in (Raster.COMPUTE, Raster.POINTS):
        r = Renderer(gl, info, attr, raster=raster, width=W, height=H)
        r.add_batch(batch)
        assert r.scene.skipped == 3
        ids = r.render(cam, W, H, r.style()).ids
        shown = set(ids[ids != EMPTY].tolist())
        assert shown == {1, 3, 5}, shown      # the points behind the skipped ones show through
        r.release()


def test_fast_format_records_with_nonfinite_shown_values_are_hidden():
    from progressive.loaders.records import pack_records
    from progressive.loaders.types import nonfinite_records

    attr = AttributeInfo("reflectance", AttributeKind.SCALAR, np.dtype("f4"))
    words = np.array([1.0, np.nan, 2.0, np.inf], dtype=np.float32).view(np.uint32)
    records = np.zeros((4, 4), dtype=np.uint32)
    records[:, 3] = words
    batch = Batch(start=0, xyz=records[:, :3].view(np.float32), records=records.copy(),
                  nonfinite_values={"reflectance": 2})
    packed = pack_records(batch, attr, 0.0)
    assert nonfinite_records(packed)[0] == 2 and nonfinite_records(records)[0] == 0
    other = AttributeInfo("intensity", AttributeKind.SCALAR, np.dtype("f4"))
    unmasked = pack_records(Batch(start=0, xyz=records[:, :3].view(np.float32), records=records.copy()), other, 0.0)
    assert nonfinite_records(unmasked)[0] == 0


@pytest.mark.parametrize("origin_z", [0.0, 3e37, -3e37])
@pytest.mark.parametrize("scale", [1e38, -1e38])
@pytest.mark.parametrize("offset", [0.0, -1e38, -3e38, 3e38])
def test_elevation_words_that_overflow_are_hidden_as_pack_records_hides_them(offset, scale, origin_z):
    """A LAS batch's elevation words are checked by the ends of its z alone (their float32
    is monotonic in z): the count equals that of the reference's records, computed from
    every point's position, whatever the scale's sign and the origin."""
    from progressive.loaders.las import _column_ends
    from progressive.loaders.records import pack_records
    from progressive.loaders.types import Grid, nonfinite_records
    from progressive.scene import _hidden_points

    cells = np.array([[0, 0, 0], [0, 0, 1], [0, 0, 3], [0, 0, 2]], dtype=np.int32)
    grid = Grid(cells, (1.0, 1.0, scale), (0.0, 0.0, 0.0), (0.0, 0.0, origin_z))
    ends = np.float64(_column_ends(cells)) * (1.0, 1.0, scale)
    batch = Batch(start=0, bounds=(ends.min(axis=0), ends.max(axis=0)), grid=grid)
    attr = AttributeInfo("elevation", AttributeKind.SCALAR, np.dtype("f8"), offset)
    hidden = nonfinite_records(pack_records(batch, attr, origin_z))[0]
    if (offset, scale, origin_z) in ((0.0, 1e38, 0.0), (-3e38, 1e38, 0.0)):
        assert hidden == (0 if offset == 0 else 3)
    assert _hidden_points(batch, attr, origin_z) == hidden
    assert _hidden_points(batch.rows(1, 4), attr, origin_z) == nonfinite_records(
        pack_records(batch.rows(1, 4), attr, origin_z))[0]      # without bounds: from every word


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_nonfinite_count_equals_a_count_of_the_mask(dtype):
    """The loaders' count of NaN/Inf values (a sum first, then the mask where the sum is not
    finite) against numpy's mask: none, each kind, both infinities (whose sum is NaN), and
    finite values whose sum overflows; no warning."""
    big = np.finfo(dtype).max
    rng = np.random.default_rng(5)
    cases = [rng.normal(size=1000), np.full(1000, big), np.array([big, -big, big])]
    for bad in ([np.nan], [np.inf], [-np.inf], [np.inf, -np.inf], [np.nan, np.inf, np.nan]):
        values = rng.normal(size=1000)
        values[rng.choice(1000, len(bad), replace=False)] = bad
        cases.append(values)
    for values in cases:
        values = values.astype(dtype)
        assert nonfinite_count(values) == np.count_nonzero(~np.isfinite(values))
    assert nonfinite_count(np.arange(10)) == 0


def test_bit_fields_equal_laspys():
    """A point format's bit fields read in one numpy call where one does it, else left to
    laspy: every field of formats 3 and 6 over every byte value equals laspy's, and the
    class and returns take the one call."""
    for point_format, one_call in ((3, {"classification", "return_number"}), (6, {"return_number", "number_of_returns"})):
        record = laspy.PackedPointRecord.zeros(256, laspy.PointFormat(point_format))
        taken = set()
        for name, (composed, field) in record.sub_fields_dict.items():
            record.array[composed] = np.arange(256, dtype=np.uint8)
            got = _bit_field(record.array[composed], field.mask)
            if got is not None:
                taken.add(name)
                assert got.dtype == np.uint8 and got.flags.c_contiguous
                np.testing.assert_array_equal(got, np.asarray(record[name]), err_msg=name)
        assert one_call <= taken, point_format


@pytest.mark.parametrize("point_format", [2, 3, 7, 8])
@pytest.mark.parametrize(("scales", "loud"), [((0.01, 0.001, 0.25), "red"), ((-0.01, 0.5, -1e-3), "green"),
                                              ((1.0, -1.0, 1.0), "blue")])
def test_record_ends_and_rgb_max_equal_numpy(point_format, scales, loud):
    """The open's probe takes the coordinate ends from the integers' ends and the colours'
    maximum from one copy of R, G, B: both equal numpy over laspy's scaled coordinates and
    fields, for either sign of a scale and whichever channel holds the greatest value, on
    whole record arrays and strided slices."""
    from progressive.loaders.las import Records, record_ends, rgb_max

    pf = laspy.PointFormat(point_format)
    rng = np.random.default_rng(point_format)
    array = np.zeros(5_000, dtype=pf.dtype())
    for axis in "XYZ":
        array[axis] = rng.integers(-2**31, 2**31, array.size, dtype=np.int64)
    for channel in ("red", "green", "blue"):
        array[channel] = rng.integers(0, 2**16 if channel == loud else 256, array.size)
    records = Records(pf, 0, np.float64(scales), np.float64([1e6, -2.5e5, 12.0]))
    for chunk in (array, array[1::3]):
        coords = np.stack([records.coordinates(chunk, axis) for axis in range(3)], axis=1)
        np.testing.assert_array_equal(record_ends(chunk, records), [coords.min(axis=0), coords.max(axis=0)])
        assert rgb_max(chunk) == max(int(chunk[c].max()) for c in ("red", "green", "blue"))
