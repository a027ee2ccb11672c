"""One orientation everywhere: a ball in the +x, +y quadrant, shallow in depth,
reconstructed locally (``import fpscan``) and by a real ``fpscan serve`` on loopback, must
appear in the same displayed quadrant in every path a user looks at it:

- the PNG MIPs of the result folder and the PNGs the server serves to the web page
  (pixel brightness inside the plotting area each PNG's own ``fpscan:axes`` chunk names);
- the HDF5 result read with h5py and drawn with matplotlib's ``imshow`` (its default:
  row 0 at the top), read back as pixels of the drawn figure;
- the OME-TIFF (tifffile) and the OME-Zarr (ome-zarr's ``Reader``, the one
  napari-ome-zarr uses) arrays shown as napari and ImageJ show them: row 0 at the top.

The oracle is the ball's position, not the renderer: x > 0 is right of centre and, with
row 0 (the smallest y) at the top, y > 0 is below the centre — "bottom right" in the xy
picture; the shallow ball sits in the top half of the xz picture.
"""
from __future__ import annotations

import io
import subprocess
import sys
import zipfile

import numpy as np
import pytest

TOKEN = "orientation-token"
N, DX, DT, N_T, C = 16, 1e-4, 4e-8, 96, 1500.0
#: the default depth rows (fpscan.service.recon.depth): the pitch down to c·t_last = 5.7 mm
N_Z = int(C * (N_T - 1) * DT / DX) + 1
BALL = (0.45e-3, 0.3e-3, 1.0e-3)  # x, y, z (m): right of and below the centre, shallow
WANT_XY, WANT_XZ = "bottom-right", "top-right"

pytestmark = pytest.mark.timeout(300)


def _quadrant(row: float, col: float, n_rows: float, n_cols: float) -> str:
    """The quadrant of a displayed position (row 0 at the top)."""
    return f"{'top' if row < n_rows / 2 else 'bottom'}-{'left' if col < n_cols / 2 else 'right'}"


def _array_quadrant(img: np.ndarray) -> str:
    """Where the brightest sample of a 2-D array shows when displayed row 0 at the top."""
    r, c = np.unravel_index(np.argmax(img), img.shape)
    return _quadrant(r + 0.5, c + 0.5, *img.shape)


def _png_quadrant(png: bytes) -> str:
    """Where the brightest pixels lie inside the plotting area of an annotated PNG."""
    from PIL import Image

    from fpscan.service.pictures.render import png_axes

    g = png_axes(png)
    grey = np.asarray(Image.open(io.BytesIO(png)).convert("L"), dtype=np.float64)
    top, bottom = int(np.ceil(g["top"])) + 2, int(np.floor(g["bottom"])) - 2
    left, right = int(np.ceil(g["left"])) + 2, int(np.floor(g["right"])) - 2
    area = grey[top:bottom, left:right]
    rows, cols = np.nonzero(area >= area.max() - 1)
    return _quadrant(rows.mean(), cols.mean(), *area.shape)


def _imshow_quadrant(img: np.ndarray) -> str:
    """Draw ``img`` with matplotlib's ``imshow`` defaults (what a user of h5py types) and
    find the brightest drawn pixel inside the axes."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(4, 4), dpi=100)
    canvas = FigureCanvasAgg(fig)
    ax = fig.add_axes((0.1, 0.1, 0.8, 0.8))
    ax.imshow(img, cmap="gray")  # defaults: origin="upper"
    canvas.draw()
    rgba = np.asarray(canvas.buffer_rgba())[..., 0].astype(float)
    box = ax.get_window_extent()
    h = rgba.shape[0]
    area = rgba[int(h - box.y1) + 2:int(h - box.y0) - 2, int(box.x0) + 2:int(box.x1) - 2]
    rows, cols = np.nonzero(area >= area.max() - 1)
    return _quadrant(rows.mean(), cols.mean(), *area.shape)


def _data(tmp_path):
    import fpscan

    x = (np.arange(N) - (N - 1) / 2) * DX
    yy, xx = np.meshgrid(x, x, indexing="ij")
    pos = np.stack([xx.ravel(), yy.ravel()], axis=1)
    alines = fpscan.ball_alines(pos, [fpscan.Ball(*BALL, radius=1.5e-4, amplitude=1.0)], DT, N_T, C)
    data = alines.T.reshape(N_T, N, N).astype(np.float32)  # (n_t, n_y, n_x)
    np.save(tmp_path / "data.npy", data)
    return data


def _zarr_read(path):
    """(level-0 array, multiscales metadata, group attributes) through ome-zarr's Reader."""
    import zarr
    from ome_zarr.io import parse_url
    from ome_zarr.reader import Reader

    nodes = list(Reader(parse_url(str(path)))())
    assert nodes, f"ome-zarr's Reader found no image in {path}"
    node = nodes[0]
    return np.asarray(node.data[0]), node.metadata, dict(zarr.open_group(str(path), mode="r").attrs)


def test_one_orientation_in_every_path(server, tmp_path):
    import h5py
    import tifffile

    import fpscan
    from fpscan.clients.http import field_of

    data = _data(tmp_path)
    seen: dict[str, str] = {}
    seen_xz: dict[str, str] = {}

    # -- locally, through the public package and the CLI's export
    ds = fpscan.GridDataset(data=data, dx=DX, dy=DX, dt=DT, sound_speed=C)
    rec = fpscan.reconstruct(ds, "ner")
    fpscan.write_result(tmp_path / "local", rec, input_id="orientation")
    seen["local PNG MIP xy"] = _png_quadrant((tmp_path / "local" / "mip_xy.png").read_bytes())
    seen_xz["local PNG MIP xz"] = _png_quadrant((tmp_path / "local" / "mip_xz.png").read_bytes())
    for fmt, name in (("ome-tiff", "p0.ome.tif"), ("ome-zarr", "p0.ome.zarr")):
        done = subprocess.run([sys.executable, "-m", "fpscan", "export", str(tmp_path / "local" / "volume.h5"),
                               "--format", fmt, "-o", str(tmp_path / name)],
                              capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, done.stderr
    with tifffile.TiffFile(tmp_path / "p0.ome.tif") as tif:
        assert tif.series[0].axes == "ZYX"
        arr = tif.asarray()
        assert "p0 unit: a.u." in tif.ome_metadata and "row 0 at the top" in tif.ome_metadata
    seen["local OME-TIFF (row 0 top)"] = _array_quadrant(arr.max(axis=0))
    arr, meta, attrs = _zarr_read(tmp_path / "p0.ome.zarr")
    seen["local OME-Zarr (row 0 top)"] = _array_quadrant(arr.max(axis=0))
    seen_xz["local OME-Zarr xz"] = _array_quadrant(arr.max(axis=1))
    assert attrs["fpscan"]["p0_unit"] == "a.u." and "row 0 at the top" in attrs["fpscan"]["orientation"]
    with h5py.File(tmp_path / "local" / "volume.h5", "r") as f:
        p0 = f["p0"][()]
        assert f.attrs["p0_unit"] == "a.u." and f["p0"].attrs["units"] == "a.u."
        assert "row 0 at the top" in f.attrs["orientation"]
    seen["local HDF5 h5py + imshow"] = _imshow_quadrant(p0.max(axis=0))
    seen_xz["local HDF5 h5py + imshow xz"] = _imshow_quadrant(p0.max(axis=1))

    # -- on the server: the served PNGs (what the web page shows) and the downloads
    with fpscan.Client(server, token=TOKEN) as api:
        dataset_id = api.upload_dataset(tmp_path / "data.npy", "npy", dt=DT, dx=DX)
        job = api.start_reconstruction(dataset_id=dataset_id, method="ner")
        api.wait(job, timeout=240)
        links = field_of(api.get_job(job), "links")
        for plane in ("xy", "xz"):
            api.download_mip(job, plane, tmp_path / f"served_{plane}.png")
        api.export(job, "ome-tiff", tmp_path / "served.ome.tif")
        got = api.export(job, "ome-zarr", tmp_path / "served.ome.zarr")
        api.download_volume(job, tmp_path / "served.h5")
    assert got == tmp_path / "served.ome.zarr" and got.is_dir()
    assert not list(tmp_path.glob(".served.ome.zarr*"))  # the zip downloaded beside it is gone
    seen["server PNG MIP xy (web page)"] = _png_quadrant((tmp_path / "served_xy.png").read_bytes())
    seen_xz["server PNG MIP xz (web page)"] = _png_quadrant((tmp_path / "served_xz.png").read_bytes())
    with tifffile.TiffFile(tmp_path / "served.ome.tif") as tif:
        seen["server OME-TIFF (row 0 top)"] = _array_quadrant(tif.asarray().max(axis=0))
    arr, meta, attrs = _zarr_read(tmp_path / "served.ome.zarr")
    seen["server OME-Zarr (row 0 top)"] = _array_quadrant(arr.max(axis=0))
    with h5py.File(tmp_path / "served.h5", "r") as f:
        p0, z, y, x = f["p0"][()], f["z"][()], f["y"][()], f["x"][()]
    seen["server HDF5 h5py + imshow"] = _imshow_quadrant(p0.max(axis=0))

    print("\norientation (xy, displayed):", *(f"  {k}: {v}" for k, v in seen.items()), sep="\n")
    print("orientation (xz, displayed):", *(f"  {k}: {v}" for k, v in seen_xz.items()), sep="\n")
    assert set(seen.values()) == {WANT_XY}, seen
    assert set(seen_xz.values()) == {WANT_XZ}, seen_xz
    assert field_of(links, "export_ome-zarr") == f"/api/jobs/{job}/export/ome-zarr"

    # ome-zarr's reader: shape, axes in micrometer, scale = voxel size in µm, translation
    # = the first sample's position in µm; the same numbers as the HDF5 volume
    print("ome-zarr Reader:", arr.shape, meta["axes"], meta["coordinateTransformations"][0])
    assert arr.shape == p0.shape == (N_Z, N, N)
    np.testing.assert_array_equal(arr, p0.astype(np.float32))
    assert [a["name"] for a in meta["axes"]] == ["z", "y", "x"]
    assert {a.get("unit") for a in meta["axes"]} == {"micrometer"}
    scale, translation = meta["coordinateTransformations"][0]
    assert scale["scale"] == pytest.approx([(z[1] - z[0]) * 1e6, DX * 1e6, DX * 1e6])
    assert translation["translation"] == pytest.approx([z[0] * 1e6, y[0] * 1e6, x[0] * 1e6])


def test_p0_unit_is_pa_for_a_calibrated_scan(tmp_path):
    """A scan whose instrument states its volts-to-pascal calibration gives p0 in Pa — in
    the HDF5 result, the OME-TIFF description and the OME-Zarr attributes; without it
    a.u.; an unknown unit in the instrument is refused."""
    import h5py
    import tifffile

    import fpscan
    from fpscan.driver.scanfile import ScanFile
    from tests.storage.storage_helpers import build_plan

    plan = build_plan(8, 8, 64)
    pos = np.asarray(plan["points"]["positions"], dtype=np.float64)
    dt, c = plan["acquisition"]["dt"], plan["acquisition"]["sound_speed"]
    alines = fpscan.ball_alines(pos, [fpscan.Ball(x=0.0, y=0.0, z=0.5e-3, radius=1.5e-4, amplitude=1.0)],
                                dt, 64, c)
    scale = float(np.abs(alines).max()) / 30000.0
    units = {}
    for name, instrument in (("pa", {"idn": "t", "pressure_unit": "Pa"}), ("au", {"idn": "t"})):
        path = tmp_path / f"{name}.h5"
        with ScanFile.create(path, plan, instrument=instrument, software_version="test") as sf:
            for k in range(len(pos)):
                sf.append(k, np.round(alines[k] / scale).astype(np.int16),
                          dict(run_id=1, boot_id=1, point_index=k, pulse_number=k, timestamp_s=0.01 * k,
                               bias_wavelength_m=1.55e-6, dc_level=1.0, pulse_energy_j=1e-3, dt_s=dt,
                               scale=scale, offset=0.0))
        assert fpscan.pressure_unit(fpscan.read_scan(path).instrument) == ("Pa" if name == "pa" else "a.u.")
        rec = fpscan.reconstruct(fpscan.load_dataset(path), "ner")
        fpscan.write_result(tmp_path / name, rec, input_id=name)
        vol = tmp_path / name / "volume.h5"
        fpscan.export_file(vol, tmp_path / f"{name}.ome.tif", "ome-tiff")
        fpscan.export_file(vol, tmp_path / f"{name}.ome.zarr", "ome-zarr")
        with h5py.File(vol, "r") as f:
            unit = f.attrs["p0_unit"]
            assert f["p0"].attrs["units"] == unit
        with tifffile.TiffFile(tmp_path / f"{name}.ome.tif") as tif:
            assert f"p0 unit: {unit}" in tif.ome_metadata
        assert _zarr_read(tmp_path / f"{name}.ome.zarr")[2]["fpscan"]["p0_unit"] == unit
        assert fpscan.read_result(vol).p0_unit == unit
        units[name] = unit
    assert units == {"pa": "Pa", "au": "a.u."}
    with pytest.raises(ValueError, match="pressure_unit must be one of Pa, a.u."):
        fpscan.pressure_unit({"pressure_unit": "mV"})
    with pytest.raises(ValueError, match="export format must be one of .*ome-tiff, ome-zarr"):
        fpscan.export_file(vol, tmp_path / "x.png", "png")


def test_ome_zarr_zip_holds_one_folder(server, tmp_path):
    """The HTTP download is a zip of one folder ``<job>.ome.zarr`` (what a user unzips
    and drops on napari), cached in the result folder after the first request."""
    import httpx

    import fpscan

    _data(tmp_path)
    with fpscan.Client(server, token=TOKEN) as api:
        dataset_id = api.upload_dataset(tmp_path / "data.npy", "npy", dt=DT, dx=DX)
        job = api.start_reconstruction(dataset_id=dataset_id, method="ner")
        api.wait(job, timeout=240)
    url = f"{server}/api/jobs/{job}/export/ome-zarr"
    r = httpx.get(url, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=60)
    assert r.status_code == 200 and r.headers["content-type"] == "application/zip"
    assert f'filename="{job}.ome.zarr.zip"' in r.headers["content-disposition"]
    names = zipfile.ZipFile(io.BytesIO(r.content)).namelist()
    assert {n.split("/", 1)[0] for n in names} == {f"{job}.ome.zarr"}
    assert f"{job}.ome.zarr/zarr.json" in names and any("/s0/" in n for n in names)  # Zarr v3 (NGFF 0.5)
    again = httpx.get(url, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=60)
    assert again.content == r.content
    # fpscan export from the server's job: the unpacked folder, opened by ome-zarr's Reader
    out = tmp_path / "cli.ome.zarr"
    done = subprocess.run([sys.executable, "-m", "fpscan", "export", "--server", server, "--token", TOKEN,
                           "--job", job, "--format", "ome-zarr", "-o", str(out)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == str(out), done.stderr
    assert _zarr_read(out)[0].shape == (N_Z, N, N)
    # the same read access as the OME-TIFF beside it
    tif = url.replace("ome-zarr", "ome-tiff")
    assert httpx.get(url, timeout=10).status_code == httpx.get(tif, timeout=10).status_code
