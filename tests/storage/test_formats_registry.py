"""The registry of file formats (fpscan.service.formats): a format added in one place (a module
with ``sniff``/``load`` and a ``Format``, registered) is detected and loaded by every reader
of files — the library's loader, the CLI's ``--format`` and its reconstruction — and the
hostile-file checks and the single open hold for it as for the built-in formats."""
from __future__ import annotations

import os

import h5py
import numpy as np
import pytest

from fpscan.service import formats
from fpscan.service.formats import Format, Source
from fpscan.service.recon.dataset import GridDataset
from fpscan.service.storage.loader import detect_format, input_formats, load_dataset, load_wavelengths
from tests.storage.storage_helpers import build_plan

TOY_MAGIC = b"TOY-GRID/1"


# -- a toy format, as a newcomer would write its module: sniff, load, write ------------------
def toy_sniff(source: Source) -> bool:
    return source.head.startswith(TOY_MAGIC)


def toy_load(source: Source, *, c: float | None = None, **_) -> GridDataset:
    """Text: the magic, ``dt dx`` (s, m), then one row of n_x samples per time step."""
    assert source.fh is not None
    lines = source.fh.read().decode().splitlines()
    dt, dx = (float(v) for v in lines[1].split())
    data = np.array([[float(v) for v in row.split()] for row in lines[2:]])
    return GridDataset(data=data, dx=dx, dt=dt, sound_speed=1500.0 if c is None else c, source="toy")


def toy_write(path, data: np.ndarray, dt: float, dx: float) -> None:
    rows = "\n".join(" ".join(repr(float(v)) for v in row) for row in data)
    path.write_text(f"{TOY_MAGIC.decode()}\n{dt!r} {dx!r}\n{rows}\n")


TOY = Format(name="toy", title="toy grid text", container="file", sniff=toy_sniff, load=toy_load,
             write=toy_write, input=True, noun="a toy grid text")


@pytest.fixture
def toy():
    """The toy format registered for the test only."""
    formats.register(TOY)
    try:
        yield TOY
    finally:
        formats.unregister(TOY.name)


def _toy_file(tmp_path):
    data = np.random.default_rng(3).standard_normal((64, 9))
    path = tmp_path / "grid.toy"
    toy_write(path, data, 2e-8, 1e-4)
    return path, data


def test_a_registered_format_is_detected_loaded_and_listed(toy, tmp_path):
    path, data = _toy_file(tmp_path)
    assert formats.detect(path) == "toy" and detect_format(path) == "toy"
    assert "toy" in input_formats() and "toy" in formats.names(input=True)
    assert "toy" not in formats.names(upload=True)  # not offered to uploads unless it says so
    ds = load_dataset(path)  # the library's one loader, by content
    assert isinstance(ds, GridDataset) and ds.source == "toy"
    np.testing.assert_array_equal(ds.data, data)
    assert (ds.dt, ds.dx, ds.sound_speed) == (2e-8, 1e-4, 1500.0)
    assert load_dataset(path, "toy", sound_speed=1540.0).sound_speed == 1540.0  # by name, options as for every format


def test_a_registered_format_reaches_the_cli(toy, tmp_path, capsys):
    """``fpscan recon`` on the toy file: detected, reconstructed (the CLI has no line for
    the format), and ``--format toy`` is a valid choice."""
    from fpscan.clients.cli import main

    path, data = _toy_file(tmp_path)
    assert main(["recon", str(path), "--method", "ner", "-q", "--out", str(tmp_path / "r")]) == 0
    with h5py.File(tmp_path / "r" / "volume.h5", "r") as f:
        assert f["p0"].shape[-1] == data.shape[1] and f.attrs["method"] == "ner"
    assert main(["recon", str(path), "--format", "toy", "--method", "ner", "-q",
                 "--out", str(tmp_path / "r2")]) == 0


def test_an_unregistered_format_is_gone(tmp_path):
    path, _ = _toy_file(tmp_path)
    formats.register(TOY)
    formats.unregister("toy")
    assert "toy" not in formats.names()
    with pytest.raises(ValueError, match="neither HDF5 nor a NumPy .npy array"):
        load_dataset(path)
    with pytest.raises(ValueError, match="format must be one of"):
        load_dataset(path, "toy")


def test_hdf5_checks_hold_for_every_format(tmp_path):
    """A toy HDF5 format never sees a file the registry refuses (an external link): the
    checks are the registry's, not each reader's."""
    seen = []
    toy_h5 = Format(name="toy-h5", title="toy HDF5", container="hdf5", order=5, input=True,
                    sniff=lambda s: s.attr("format") == "toy-h5/1",
                    load=lambda s, **_: seen.append(s.path) or GridDataset(
                        data=s.h5["data"][()], dx=1e-4, dt=1e-8, sound_speed=1500.0, source="toy-h5"))
    (tmp_path / "other.h5").touch()
    with h5py.File(tmp_path / "good.h5", "w") as f:
        f.attrs["format"] = "toy-h5/1"
        f["data"] = np.ones((8, 4))
    with h5py.File(tmp_path / "linked.h5", "w") as f:
        f.attrs["format"] = "toy-h5/1"
        f["data"] = np.ones((8, 4))
        f["elsewhere"] = h5py.ExternalLink("other.h5", "/x")
    formats.register(toy_h5)
    try:
        assert load_dataset(tmp_path / "good.h5").source == "toy-h5"
        with pytest.raises(ValueError, match="external link"):
            load_dataset(tmp_path / "linked.h5")
        with pytest.raises(ValueError, match="external link"):
            formats.detect(tmp_path / "linked.h5")
    finally:
        formats.unregister("toy-h5")
    assert seen == [tmp_path / "good.h5"]


def test_a_file_is_opened_once_per_load(make_scan, tmp_path, monkeypatch):
    """Detecting, checking and reading a scan file (an IPASC file at its second
    wavelength, every wavelength of a two-wavelength scan) opens the HDF5 file once."""
    from fpscan.service.formats.ipasc import export_scan
    from tests.storage.test_storage_ipasc_wavelengths import WAVELENGTHS, two_wavelength_scan

    scan = make_scan("scan.h5", build_plan(3, 3, 16))
    two = two_wavelength_scan(tmp_path / "two.h5", build_plan(3, 2, 16, wavelengths=WAVELENGTHS))
    ipasc = export_scan(two, tmp_path / "two_ipasc.h5")
    opened = []
    real_init = h5py.File.__init__

    def counting_init(self, name, *args, **kwargs):
        if isinstance(name, (str, os.PathLike)):  # an open by file name (not h5py wrapping an open id)
            opened.append(str(name))
        real_init(self, name, *args, **kwargs)

    monkeypatch.setattr(h5py.File, "__init__", counting_init)
    assert load_dataset(scan).source == "fpscan"
    assert opened == [str(scan)]
    opened.clear()
    ds = load_dataset(ipasc, wavelength=1)
    assert ds.source == "ipasc" and ds.wavelengths == (WAVELENGTHS[1],)
    assert opened == [str(ipasc)]
    for path in (two, ipasc):
        opened.clear()
        every = load_wavelengths(path, wavelength="all")
        assert [d.wavelengths for d in every] == [(w,) for w in WAVELENGTHS]
        assert [d.meta["wavelength_index"] for d in every] == [0, 1] and opened == [str(path)]
        # the same data as one load per wavelength (a load each)
        for k, d in enumerate(every):
            np.testing.assert_array_equal(d.alines, load_dataset(path, wavelength=k).alines)
