"""Every picture fpscan draws agrees: one off-centre ball (asymmetric in x, y and z) must
appear at its true position in mm -- read off each PNG's own axes -- in the live preview
of a scan, the result MIPs and depth slice of the reconstruction job, and the plan's mask
preview. A flipped axis, a stretched aspect or an axis in the wrong unit moves the spot
by far more than the tolerance (the ball sits 0.35-0.55 mm off the centre)."""
from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image as PILImage

from fpscan.driver.scanfile import ScanFile
from fpscan.service.pictures.render import png_axes
from tests.storage.storage_helpers import PITCH, build_plan
from tests.waits import HANG_S

N, N_T, DT = 24, 128, 2e-8
C = 1490.0  # the helper plan's sound speed
BALL = {"x": 0.55e-3, "y": 0.35e-3, "z": 1.0e-3}  # m; lattice points at (i - 11.5)·0.1 mm


def _spot_mm(png: bytes) -> tuple[float, float]:
    """(horizontal, vertical) mm of the brightest pixel inside the picture's plotting area,
    mapped with the geometry the PNG carries (independent of the renderer's code)."""
    g = png_axes(png)
    grey = np.asarray(PILImage.open(io.BytesIO(png)).convert("L"), dtype=np.float64)
    top, bottom = int(np.ceil(g["top"])) + 2, int(np.floor(g["bottom"])) - 2
    left, right = int(np.ceil(g["left"])) + 2, int(np.floor(g["right"])) - 2
    area = grey[top:bottom, left:right]
    rows, cols = np.nonzero(area >= area.max() - 1)
    row, col = rows.mean() + top + 0.5, cols.mean() + left + 0.5
    h_left, h_right, v_bottom, v_top = g["extent_mm"]
    h = h_left + (col - g["left"]) / (g["right"] - g["left"]) * (h_right - h_left)
    v = v_top + (row - g["top"]) / (g["bottom"] - g["top"]) * (v_bottom - v_top)
    return h, v


def _ball_scan(path) -> str:
    from fpscan.physics.balls import Ball, ball_alines

    plan = build_plan(N, N, N_T)  # dt = DT, c = C
    assert plan["acquisition"]["dt"] == DT and plan["acquisition"]["sound_speed"] == C
    pos = np.asarray(plan["points"]["positions"], dtype=np.float64)
    alines = ball_alines(pos, [Ball(x=BALL["x"], y=BALL["y"], z=BALL["z"], radius=1.5e-4, amplitude=1.0)],
                         DT, N_T, C)
    scale = float(np.abs(alines).max()) / 30000.0
    with ScanFile.create(path, plan, instrument={"idn": "test"}, software_version="test") as sf:
        for k in range(len(pos)):
            sf.append(k, np.round(alines[k] / scale).astype(np.int16),
                      dict(run_id=1, boot_id=1, point_index=k, pulse_number=k, timestamp_s=0.01 * k,
                           bias_wavelength_m=1.55e-6, dc_level=1.0, pulse_energy_j=1e-3, dt_s=DT,
                           scale=scale, offset=0.0))
    return str(path)


def _assert_at(png: bytes, expected: tuple[float, float], what: str, tol_mm: float = 0.2) -> None:
    h_left, h_right, v_bottom, v_top = png_axes(png)["extent_mm"]
    assert h_left < h_right, f"{what}: x/y must grow to the right"
    assert v_top < v_bottom, f"{what}: row 0 at the top: y and depth must point down"
    h, v = _spot_mm(png)
    assert abs(h - expected[0]) < tol_mm and abs(v - expected[1]) < tol_mm, \
        f"{what}: spot at ({h:.3f}, {v:.3f}) mm, the ball is at {expected} mm"


def test_one_orientation_and_mm_axes_in_every_picture(tmp_path):
    pytest.importorskip("fpscan.service.recon")
    from fpscan.service.jobs.preview import PreviewState, render_preview
    from fpscan.service.jobs.work import run_reconstruction
    from fpscan.service.pictures.render import render_result_slice

    scan = _ball_scan(tmp_path / "ball.h5")
    bx, by, bz = (BALL[k] * 1e3 for k in ("x", "y", "z"))
    want = {"xy": (bx, by), "xz": (bx, bz), "yz": (by, bz)}

    refresh = render_preview(scan)  # what the server's preview worker computes ...
    state = PreviewState(version=1, points_used=refresh["points_used"], mips=refresh["mips"],
                         axes=refresh["axes"])
    live = {plane: state.png(plane) for plane in state.planes}  # ... and serves
    out = tmp_path / "result"
    run_reconstruction({"input": {"kind": "scan", "path": scan}, "params": {"method": "ner"},
                        "out_dir": str(out), "input_id": "scan:test"})
    for plane, spot in want.items():
        _assert_at(live[plane], spot, f"live preview {plane}")
        _assert_at((out / f"mip_{plane}.png").read_bytes(), spot, f"result MIP {plane}")
    import h5py

    with h5py.File(out / "volume.h5", "r") as f:  # the row nearest the ball's depth, on the volume's own grid
        k = int(np.argmin(np.abs(f["z"][...] - BALL["z"])))
    _assert_at(render_result_slice(out / "volume.h5", k), want["xy"], f"depth slice {k}")

    # aspect in mm: the xy pictures are square (a square lattice), the xz ones are as
    # tall as the recorded depth is deep relative to the lattice width
    for png in (live["xy"], (out / "mip_xy.png").read_bytes()):
        g = png_axes(png)
        assert (g["bottom"] - g["top"]) == pytest.approx(g["right"] - g["left"], rel=0.02)
    # (the live previews' xz/yz too: not stretched to squares)
    for what, png in (("result MIP xz", (out / "mip_xz.png").read_bytes()), ("live preview xz", live["xz"]),
                      ("live preview yz", live["yz"])):
        g = png_axes(png)
        h_left, h_right, v_bottom, v_top = g["extent_mm"]
        assert (g["bottom"] - g["top"]) / (g["right"] - g["left"]) == \
            pytest.approx(abs(v_bottom - v_top) / (h_right - h_left), rel=0.03), what
        assert abs(abs(v_bottom - v_top) - (h_right - h_left)) > 0.1, f"{what}: depth and width differ in mm"


    # the same volume as OME-TIFF for ImageJ/napari, through the CLI: right shape, axes
    # and physical voxel sizes (µm), the same numbers (float32)
    import subprocess
    import sys

    import h5py
    import tifffile

    done = subprocess.run([sys.executable, "-m", "fpscan", "export", str(out / "volume.h5"),
                           "-o", str(tmp_path / "p0.ome.tif")], capture_output=True, text=True, timeout=HANG_S)
    assert done.returncode == 0, done.stderr
    with h5py.File(out / "volume.h5", "r") as f:
        p0, z, y, x = f["p0"][()], f["z"][()], f["y"][()], f["x"][()]
    with tifffile.TiffFile(tmp_path / "p0.ome.tif") as tif:
        assert tif.is_ome and tif.series[0].axes == "ZYX" and tif.series[0].shape == p0.shape
        np.testing.assert_array_equal(tif.asarray(), p0.astype(np.float32))
        pixels = tif.ome_metadata.split("<Pixels ", 1)[1].split(">", 1)[0]
    attrs = dict(a.split("=", 1) for a in pixels.split())
    for key, v in (("PhysicalSizeX", x), ("PhysicalSizeY", y), ("PhysicalSizeZ", z)):
        assert float(attrs[key].strip('"')) == pytest.approx((v[1] - v[0]) * 1e6, rel=1e-9), key
        assert attrs[f"{key}Unit"].strip('"') == "µm"
    assert float(attrs["PhysicalSizeX"].strip('"')) == pytest.approx(PITCH * 1e6)
    assert float(attrs["PhysicalSizeZ"].strip('"')) == pytest.approx(PITCH * 1e6)  # the default dz: the pitch


def test_mask_preview_has_the_same_orientation(tmp_path):
    """The plan preview draws points the same way: a mask of points in the +x, +y corner
    appears in that corner (y down, as every picture)."""
    from fpscan.service.plans import make_plan, preview_png

    idx = [[20, 18], [21, 18], [20, 19], [21, 19]]  # x = 0.85-0.95 mm, y = 0.65-0.75 mm
    plan = make_plan(kind="points", lattice={"n_x": N, "n_y": N, "pitch": PITCH},
                     params={"indices": idx}, acquisition={"n_t": N_T, "dt": DT})
    png = preview_png(plan)
    g = png_axes(png)
    rgb = np.asarray(PILImage.open(io.BytesIO(png)).convert("RGB"), dtype=np.int32)
    sat = np.abs(rgb[..., 0] - rgb[..., 1]) + np.abs(rgb[..., 1] - rgb[..., 2])
    top, bottom, left, right = (int(g["top"]) + 2, int(g["bottom"]) - 2, int(g["left"]) + 2,
                                int(g["right"]) - 2)
    rows, cols = np.nonzero(sat[top:bottom, left:right] > 60)  # the coloured markers
    h_left, h_right, v_bottom, v_top = g["extent_mm"]
    assert v_top < v_bottom  # y down (row 0 at the top), as in every picture
    h = h_left + (cols.mean() + left + 0.5 - g["left"]) / (g["right"] - g["left"]) * (h_right - h_left)
    v = v_top + (rows.mean() + top + 0.5 - g["top"]) / (g["bottom"] - g["top"]) * (v_bottom - v_top)
    assert abs(h - 0.9) < 0.15 and abs(v - 0.7) < 0.15, (h, v)


def test_large_plan_preview_has_the_same_orientation():
    """A plan above ``PREVIEW_DETAIL_POINTS`` (what the API and the web result page show
    for the README's 226 x 226 plan) is drawn as an image on its lattice by the same
    renderer: mm axes at equal aspect, y down, the axes chunk. A 140 x 140 lattice missing
    its +x, +y corner (40 x 40 points): the unscanned pixels sit in that corner."""
    from fpscan.driver.plan import plan_id_of
    from fpscan.service.api.plans import PREVIEW_DETAIL_POINTS, preview_png

    n, hole = 140, 100
    idx = [[i, j] for j in range(n) for i in range(n) if not (i >= hole and j >= hole)]
    assert len(idx) > PREVIEW_DETAIL_POINTS
    c = lambda i: (i - (n - 1) / 2) * PITCH
    plan = {"format": "fpscan-plan/1", "lattice": {"n_x": n, "n_y": n, "pitch": PITCH},
            "mask": {"kind": "points", "params": {}},
            "points": {"indices": idx, "positions": [[c(i), c(j)] for i, j in idx],
                       "weights": [PITCH ** 2] * len(idx)},
            "order": "rows", "acquisition": {"n_t": N_T, "dt": DT, "averages": 1, "wavelengths": [7.5e-7],
                                             "prf": 0.0, "sound_speed": C}}
    plan["id"] = plan_id_of(plan)
    png = preview_png(plan)
    g = png_axes(png)
    h_left, h_right, v_bottom, v_top = g["extent_mm"]
    half = n / 2 * PITCH * 1e3
    assert (h_left, h_right) == pytest.approx((-half, half), abs=0.1) and h_left < h_right
    assert (v_bottom, v_top) == pytest.approx((half, -half), abs=0.1)  # y down
    assert (g["bottom"] - g["top"]) == pytest.approx(g["right"] - g["left"], rel=0.02)  # square in mm
    rgb = np.asarray(PILImage.open(io.BytesIO(png)).convert("RGB"), dtype=np.int32)
    sat = np.abs(rgb[..., 0] - rgb[..., 1]) + np.abs(rgb[..., 1] - rgb[..., 2])
    top, bottom, left, right = (int(g["top"]) + 2, int(g["bottom"]) - 2, int(g["left"]) + 2,
                                int(g["right"]) - 2)
    rows, cols = np.nonzero(sat[top:bottom, left:right] < 20)  # the grey, unscanned cells
    h = h_left + (cols.mean() + left + 0.5 - g["left"]) / (g["right"] - g["left"]) * (h_right - h_left)
    v = v_top + (rows.mean() + top + 0.5 - g["top"]) / (g["bottom"] - g["top"]) * (v_bottom - v_top)
    corner = ((hole + n) / 2 - (n - 1) / 2) * PITCH * 1e3  # the hole's centre, mm
    assert abs(h - corner) < 0.3 and abs(v - corner) < 0.3, (h, v, corner)
    assert rows.size == pytest.approx((bottom - top) * (right - left) * (n - hole) ** 2 / n ** 2, rel=0.15)


def _ink(png: bytes) -> np.ndarray:
    """Where a picture is not white (text, lines, colours): a boolean image."""
    return np.asarray(PILImage.open(io.BytesIO(png)).convert("L")) < 200


@pytest.mark.parametrize("large", [False, True])
def test_mask_preview_titles_fit_and_weights_carry_no_factor(large):
    """The README's equi-steradian plan (226 x 226 at 60 µm, 1625 points): the preview's
    title stays inside the picture (no ink in the first and last columns above the plot;
    it was cut at both sides), in the markers' and the lattice's drawing alike; its weights
    (up to 0.3 mm²) are drawn in mm², so no power of ten sits beside the colour bar (no ink
    between the title and the bar's top)."""
    from fpscan.service.plans import make_plan
    from fpscan.service.plans import preview_png as marker_preview

    plan = make_plan(kind="equisteradian", lattice={"n_x": 226, "n_y": 226, "pitch": 60e-6},
                     params={"depth": 3.6e-3, "n_points": 1625}, acquisition={"n_t": N_T, "dt": DT})
    if large:  # the lattice drawing the API uses for plans above PREVIEW_DETAIL_POINTS, as it calls it
        from fpscan.service.pictures.render import render_lattice

        d = plan.model_dump(mode="json")
        png = render_lattice(np.asarray(d["points"]["indices"]), np.asarray(d["points"]["weights"]) * 1e12, 226, 226,
                             60e-6, title="equisteradian: 1653 of 1625 requested points on 226×226\n"
                                          "outer/inner weight ratio 9.69", colorbar_label="weight (µm²)")
    else:
        png = marker_preview(plan)
    g = png_axes(png)
    ink = _ink(png)
    above = ink[:int(g["top"]) - 4]
    assert above.any()  # the title is there
    assert not above[:, :3].any() and not above[:, -3:].any(), "the title is cut at the picture's side"
    right_of_plot = ink[:int(g["top"]) - 4, int(g["right"]) + 10:]
    rows = np.nonzero(right_of_plot.any(axis=1))[0]
    title_rows = np.nonzero(above[:, :int(g["right"])].any(axis=1))[0]
    assert rows.size == 0 or rows.max() <= title_rows.max(), "ink beside the colour bar's top (a power of ten)"


def test_colour_bar_powers_sit_in_the_unit():
    """p0 of 3e6 a.u.: the annotated MIP has nothing above its colour bar (the power went
    into the label, ``p0 (×10⁶ a.u.)``: ``fpscan.service.pictures.frame.power_in_label``), while the
    same picture of p0 up to 3 has the same (empty) band."""
    from fpscan.service.pictures.frame import power_in_label
    from fpscan.service.pictures.render import render_mip

    assert power_in_label("p0 (a.u.)", "1e6") == "p0 (×10⁶ a.u.)"
    assert power_in_label("p0 (Pa)", "1e\u22124") == "p0 (×10⁻⁴ Pa)"
    rng = np.random.default_rng(1)
    axes = (np.arange(40) * 1e-5, (np.arange(30) - 14.5) * 1e-4, (np.arange(30) - 14.5) * 1e-4)
    bands = []
    for scale in (3.0, 3e6):
        png = render_mip(rng.random((40, 30, 30)) * scale, *axes, "xy")
        g = png_axes(png)
        ink = _ink(png)
        # between the plot's top and the title: the band right of the plot, above the bar
        bands.append(ink[int(g["top"]) - 18:int(g["top"]) - 2, int(g["right"]) + 5:].sum())
    assert bands == [0, 0], bands
