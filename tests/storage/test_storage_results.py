"""Result files (fpscan.service.storage.results) and their PNG renderings (fpscan.service.pictures.render)."""
from __future__ import annotations

import io
import json
import os

import h5py
import numpy as np
import pytest
from PIL import Image as PILImage

from fpscan.service.pictures.render import (
    mip,
    render_lateral,
    render_mip,
    render_mips,
    render_result_slice,
    to_uint8,
)
from fpscan.service.storage.results import read_result, write_reconstruction, write_volume


def volume(n_z=7, n_y=5, n_x=6, dtype=np.float32):
    rng = np.random.default_rng(3)
    p0 = rng.random((n_z, n_y, n_x)).astype(dtype)
    z = np.arange(n_z) * 1.5e-5
    y = (np.arange(n_y) - (n_y - 1) / 2) * 6e-5
    x = (np.arange(n_x) - (n_x - 1) / 2) * 6e-5
    return p0, z, y, x


def test_write_read_3d(tmp_path):
    p0, z, y, x = volume()
    params = {"method": "nedner", "eps": 1e-6, "upsample": np.int64(2), "dtype": "float32",
              "weights": np.array([0.5, 0.25]), "positivity": False, "n_z": None}
    path = write_volume(tmp_path / "r.h5", p0, z, x, y, method="nedner", params=params,
                        input_id="scan-abc")
    r = read_result(path)
    assert r.p0.dtype == np.float32
    np.testing.assert_array_equal(r.p0, p0)
    np.testing.assert_array_equal(r.z, z)
    np.testing.assert_array_equal(r.y, y)
    np.testing.assert_array_equal(r.x, x)
    assert r.method == "nedner" and r.input_id == "scan-abc"
    assert r.params == {"method": "nedner", "eps": 1e-6, "upsample": 2, "dtype": "float32",
                        "weights": [0.5, 0.25], "positivity": False, "n_z": None}
    with h5py.File(path, "r") as f:  # dimension scales and one JSON attribute per parameter
        assert [f["p0"].dims[i][0].name for i in range(3)] == ["/z", "/y", "/x"]
        assert json.loads(f["params"].attrs["eps"]) == 1e-6
        assert json.loads(f["params"].attrs["weights"]) == [0.5, 0.25]
    assert [p.name for p in tmp_path.iterdir()] == ["r.h5"]  # no temporary left behind


def test_volumes_are_compressed_only_where_it_pays(tmp_path):
    """A volume that is mostly zeros is stored gzip-compressed (a few per cent of its
    size); one with noise everywhere (compresses to ~86 %) contiguous and uncompressed,
    for write speed. Both read back bit-identical with plain h5py."""
    rng = np.random.default_rng(7)
    z, y, x = (np.arange(n) * 1e-4 for n in (64, 32, 48))
    sparse = np.zeros((64, 32, 48), np.float32)
    sparse[20:30, 10:20, 15:30] = rng.random((10, 10, 15))
    noisy = (sparse + 0.01 * rng.standard_normal(sparse.shape)).astype(np.float32)
    sizes = {}
    for name, p0 in (("sparse", sparse), ("noisy", noisy)):
        path = write_volume(tmp_path / f"{name}.h5", p0, z, x, y, method="ner", params={}, input_id="t")
        with h5py.File(path, "r") as f:
            d = f["p0"]
            np.testing.assert_array_equal(d[...], p0)
            sizes[name] = (d.compression, d.chunks, d.id.get_storage_size() / p0.nbytes)
    assert sizes["sparse"][0] == "gzip" and sizes["sparse"][2] < 0.1
    assert sizes["noisy"][:2] == (None, None) and sizes["noisy"][2] == 1.0


class _Rec:  # the shape of fpscan.service.recon.Reconstruction (duck-typed; not our code under test)
    def __init__(self, p0, z, x, y, params):
        self.p0, self.z, self.x, self.y, self.params = p0, z, x, y, params


def test_write_image_2d_and_atomic_replace(tmp_path):
    p0, z, _, x = volume()
    img2 = _Rec(p0[:, 0, :].astype(np.float64), z, x, None, {"method": "ner", "eps": 1e-6})
    path = write_reconstruction(tmp_path / "r.h5", img2, input_id="d1")
    first = path.read_bytes()
    r = read_result(path)
    assert r.y is None and r.p0.shape == (7, 6) and r.method == "ner"
    # a failed write leaves the previous file untouched and no temporary behind
    bad = p0[:, 0, :].copy()
    bad[2, 3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        write_volume(path, bad, z, x, method="ner", params={}, input_id="d2")
    assert path.read_bytes() == first and len(os.listdir(tmp_path)) == 1
    # a successful one replaces it
    write_volume(path, p0[:, 1, :], z, x, method="ner", params={}, input_id="d3")
    assert read_result(path).input_id == "d3"


@pytest.mark.parametrize("kwargs, what", [
    (dict(p0=np.zeros((3, 4, 5)), y=None), "give y"),
    (dict(p0=np.zeros((3, 5)), y=np.arange(4.0)), "give y"),
    (dict(p0=np.zeros((3, 4))), r"x must have shape \(4,\)"),
    (dict(p0=np.zeros((2, 5))), r"z must have shape \(2,\)"),
    (dict(p0=np.zeros((3, 5), dtype=complex)), "real"),
    (dict(z=np.array([0.0, 2.0, 1.0])), "increasing"),
    (dict(params={"eps": float("nan")}), "JSON"),
    (dict(params={"f": object()}), "JSON"),
    (dict(method=""), "method"),
])
def test_result_bad_input(tmp_path, kwargs, what):
    args = dict(p0=np.zeros((3, 5)), z=np.arange(3.0), x=np.arange(5.0), y=None, method="ner",
                params={}, input_id="i")
    args.update(kwargs)
    with pytest.raises(ValueError, match=what):
        write_volume(tmp_path / "bad.h5", args.pop("p0"), args.pop("z"), args.pop("x"),
                     args.pop("y"), **args)
    assert not (tmp_path / "bad.h5").exists()


def test_read_result_rejects_other_files(tmp_path):
    with h5py.File(tmp_path / "other.h5", "w") as f:
        f["p0"] = np.zeros((2, 2))
    with pytest.raises(ValueError, match="fpscan-result"):
        read_result(tmp_path / "other.h5")
    with pytest.raises(FileNotFoundError):
        read_result(tmp_path / "none.h5")


def _png(data: bytes) -> np.ndarray:
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return np.asarray(PILImage.open(io.BytesIO(data)))


def test_mip_planes_against_direct_max():
    p0 = np.zeros((6, 5, 4))
    p0[4, 1, 2] = 3.0   # (z, y, x)
    p0[1, 3, 0] = 2.0
    oracle = {"xy": np.zeros((5, 4)), "xz": np.zeros((6, 4)), "yz": np.zeros((6, 5))}
    for (iz, iy, ix), v in [((4, 1, 2), 3.0), ((1, 3, 0), 2.0)]:
        oracle["xy"][iy, ix] = v
        oracle["xz"][iz, ix] = v
        oracle["yz"][iz, iy] = v
    for plane, expected in oracle.items():
        np.testing.assert_array_equal(mip(p0, plane), expected)
    np.testing.assert_array_equal(mip(p0[:, 0, :], "xz"), p0[:, 0, :])
    with pytest.raises(ValueError, match="only the xz"):
        mip(p0[:, 0, :], "xy")
    with pytest.raises(ValueError, match="plane"):
        mip(p0, "zz")


def test_raw_png_pixels_are_the_scaled_mip():
    p0, z, y, x = volume(dtype=np.float64)
    p0[0, 0, 0] = -1.0
    for plane in ("xy", "xz", "yz"):
        px = _png(render_mip(p0, z, x, y, plane, annotate=False))
        m = mip(p0, plane)
        expected = np.floor(np.clip(m / m.max(), 0, 1) * 255 + 0.5).astype(np.uint8)
        # every plane: row 0 of the array is the first PNG row (y and depth down)
        np.testing.assert_array_equal(px, expected)
    px = _png(render_lateral(p0[3], x, y, float(z[3]), annotate=False, vmin=0.0, vmax=0.5))
    np.testing.assert_array_equal(px, np.floor(np.clip(p0[3] / 0.5, 0, 1) * 255 + 0.5))
    rgb = _png(render_mip(p0, z, x, y, "xy", annotate=False, cmap="viridis"))
    assert rgb.shape == (5, 6, 3)
    assert to_uint8(np.zeros((2, 2))).max() == 0  # nothing above vmin renders black


def test_annotated_pngs(tmp_path):
    p0, z, y, x = volume(n_z=40, n_y=20, n_x=30)
    pngs = render_mips(p0, z, x, y)
    assert set(pngs) == {"xy", "xz", "yz"}
    for data in pngs.values():
        img = _png(data)
        assert img.ndim in (2, 3) and img.shape[0] > 100 and img.shape[1] > 300
    assert set(render_mips(p0[:, 0, :], z, x)) == {"xz"}
    _png(render_lateral(p0[0], x, y, float(z[0]), cmap="magma"))
    path = write_volume(tmp_path / "r.h5", p0, z, x, y, method="ner", params={}, input_id="t")
    assert _png(render_result_slice(path, 0, annotate=False)).shape == p0.shape[1:]
    with pytest.raises(ValueError, match=r"index must be an integer in \[0, 40\)"):
        render_result_slice(path, 40)
    with pytest.raises(ValueError, match="colormap"):
        render_mip(p0, z, x, y, "xy", cmap="no-such-map")
    with pytest.raises(ValueError, match="y coordinates"):
        render_mip(p0, z, x, None, "xy")
    with pytest.raises(ValueError, match="do not match"):
        render_mip(p0, z[:-1], x, y, "xy")


def test_annotated_png_shows_the_colormapped_samples_in_its_frame():
    """An annotated picture (the Pillow frame of fpscan.service.pictures.frame): 600 px wide; inside
    the plotting area its ``fpscan:axes`` chunk names, the centre of every sample's cell has
    matplotlib's colour of that sample (viridis over [vmin, vmax], row 0 at the top); text and
    ticks left of the area (the y axis) and right of it (the colour bar and its label)."""
    import matplotlib

    from fpscan.service.pictures.render import png_axes, render_png

    rng = np.random.default_rng(5)
    img = rng.random((6, 9))
    h, v = np.arange(9) * 1e-4, np.arange(6) * 1e-4
    png = render_png(img, h, v, hlabel="x", vlabel="y", cmap="viridis", vmin=0.0, vmax=1.0,
                     colorbar_label="p0 (Pa)")
    rgb = _png(png)[..., :3].astype(np.int32)
    assert rgb.shape[1] == 600
    g = png_axes(png)
    assert g["extent_mm"] == pytest.approx([-0.05, 0.85, 0.55, -0.05])  # sample edges in mm, y down
    cell_w, cell_h = (g["right"] - g["left"]) / 9, (g["bottom"] - g["top"]) / 6
    assert cell_w == pytest.approx(cell_h, rel=0.05)  # equal aspect
    want = np.asarray(matplotlib.colormaps["viridis"](img))[..., :3] * 255
    for i in range(6):
        for j in range(9):
            px = rgb[int(g["top"] + (i + 0.5) * cell_h), int(g["left"] + (j + 0.5) * cell_w)]
            assert np.abs(px - want[i, j]).max() <= 3, (i, j, px, want[i, j])
    dark = rgb.sum(axis=2) < 200
    assert dark[:, : int(g["left"]) - 2].sum() > 200  # y tick labels and the y label
    assert dark[:, int(g["right"]) + 40:].sum() > 200  # colour bar ticks, tick labels, its label
    assert dark[int(g["bottom"]) + 2:, :].sum() > 200  # x tick labels and the x label


def test_the_result_folder_is_written_by_its_format(tmp_path):
    """The result folder (volume.h5 + MIP PNGs) has one owner, fpscan.service.formats.result: its
    file names and its writer (write_folder); storage draws the MIPs and calls it. The
    folder read back through the format is the reconstruction, the pictures are
    render_mips' bytes, and a second write replaces the folder whole."""
    from types import SimpleNamespace

    from fpscan.service.formats.result import VOLUME_FILE, mip_file, read_result, write_folder
    from fpscan.service.pictures.render import render_mips
    from fpscan.service.storage.results import write_result

    z, x, y = np.arange(6) * 1e-5, np.arange(5) * 1e-4, np.arange(4) * 1e-4
    p0 = np.random.default_rng(1).standard_normal((6, 4, 5)).astype(np.float32)
    rec = SimpleNamespace(p0=p0, z=z, x=x, y=y, params={"method": "ner", "c": 1490.0}, p0_unit="a.u.")
    out = tmp_path / "result"
    summary = write_result(out, rec, input_id="t")
    assert sorted(p.name for p in out.iterdir()) == sorted([VOLUME_FILE] + [mip_file(p) for p in ("xy", "xz", "yz")])
    assert summary["planes"] == ["xy", "xz", "yz"] and summary["shape"] == [6, 4, 5]
    assert summary["max"] == pytest.approx(float(p0.max())) and summary["params_used"]["c"] == 1490.0
    back = read_result(out / VOLUME_FILE)
    np.testing.assert_array_equal(back.p0, p0)
    assert back.method == "ner" and back.input_id == "t"
    pngs = render_mips(p0, z, x, y, colorbar_label="p0 (a.u.)")
    for plane, png in pngs.items():
        assert (out / mip_file(plane)).read_bytes() == png
    # the format's writer alone: the pictures it is given, the old folder replaced
    assert write_folder(out, rec, input_id="u", mips={"xz": b"\x89PNG only one"})["planes"] == ["xz"]
    assert sorted(p.name for p in out.iterdir()) == sorted([VOLUME_FILE, mip_file("xz")])
    assert read_result(out / VOLUME_FILE).input_id == "u"
    assert not list(tmp_path.glob("result.tmp-*"))
    # a failure while writing leaves the folder as it was and no temporary folder behind
    with pytest.raises(TypeError):
        write_folder(out, rec, input_id="v", mips={"xy": "not bytes"})  # type: ignore[dict-item]
    assert read_result(out / VOLUME_FILE).input_id == "u" and not list(tmp_path.glob("result.tmp-*"))
    # the pictures from a callable, asked for once the volume is on disk (write_result draws
    # them in a thread meanwhile); one that fails leaves the folder as it was too
    seen = []

    def pictures():
        seen.extend(p.name for p in tmp_path.glob("result.tmp-*/*"))
        return {"xz": b"\x89PNG late"}

    assert write_folder(out, rec, input_id="w", mips=pictures)["planes"] == ["xz"]
    assert seen == [VOLUME_FILE] and (out / mip_file("xz")).read_bytes() == b"\x89PNG late"

    def broken():
        raise ValueError("no pictures")

    with pytest.raises(ValueError, match="no pictures"):
        write_folder(out, rec, input_id="x", mips=broken)
    assert read_result(out / VOLUME_FILE).input_id == "w" and not list(tmp_path.glob("result.tmp-*"))


def test_ome_zarr_export_is_ngff_05_with_a_pyramid_the_reader_opens_without_a_warning(tmp_path, caplog):
    """The OME-Zarr export in ome-zarr's current format (NGFF 0.5 on Zarr v3): ome-zarr's
    Reader (napari-ome-zarr's) opens it without a version-mismatch warning; a volume longer
    than PYRAMID_TOP along an axis gets halved levels, each the block means of the one above
    (the oracle: numpy's reshape-mean), chunked for lazy reading, at its voxel size and the
    position of its first voxel's centre (level 0: the first sample's)."""
    import logging

    import zarr
    from ome_zarr.io import parse_url
    from ome_zarr.reader import Reader

    from fpscan.service.formats import export_file
    from fpscan.service.formats.ngff import PYRAMID_TOP, ZARR_CHUNK

    rng = np.random.default_rng(2)
    p0 = rng.random((520, 16, 64)).astype(np.float32)  # depth 520 > PYRAMID_TOP: one level below
    z, y, x = np.arange(520) * 15e-6, (np.arange(16) - 7.5) * 1e-4, (np.arange(64) - 31.5) * 1e-4
    write_volume(tmp_path / "v.h5", p0, z, x, y, method="ner", params={}, input_id="t")
    export_file(tmp_path / "v.h5", tmp_path / "v.ome.zarr", "ome-zarr")
    with caplog.at_level(logging.DEBUG):
        nodes = list(Reader(parse_url(str(tmp_path / "v.ome.zarr")))())
    assert not [r for r in caplog.records if "mismatch" in r.getMessage().lower()], caplog.records
    group = zarr.open_group(str(tmp_path / "v.ome.zarr"), mode="r")
    assert group.metadata.zarr_format == 3 and group.attrs["ome"]["version"] == "0.5"
    levels = [np.asarray(d) for d in nodes[0].data]
    assert len(levels) == 2 and p0.shape[0] > PYRAMID_TOP
    np.testing.assert_array_equal(levels[0], p0)
    want = p0.reshape(260, 2, 8, 2, 32, 2).mean(axis=(1, 3, 5))
    np.testing.assert_allclose(levels[1], want, rtol=1e-6)
    assert all(max(d.chunksize) <= ZARR_CHUNK for d in nodes[0].data)
    transforms = nodes[0].metadata["coordinateTransformations"]
    step = np.array([15.0, 100.0, 100.0])
    first = np.array([z[0], y[0], x[0]]) * 1e6
    for k, (scale, shift) in enumerate(transforms):
        f = 2 ** k
        assert scale["scale"] == pytest.approx(step * f)
        assert shift["translation"] == pytest.approx(first + (f - 1) / 2 * step)  # the block's centre
    assert group.attrs["fpscan"]["p0_unit"] == "a.u."
