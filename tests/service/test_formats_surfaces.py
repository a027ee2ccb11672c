"""The registry of formats (fpscan.service.formats) is the one list every surface offers: the
upload's ``format`` field (OpenAPI schema and its refusal), ``GET /api/datasets/formats``
(the web page's and the HTTP client's choices; tests/web check the page) and
``fpscan recon``/``fpscan unmix --format``."""
from __future__ import annotations

import argparse

from fpscan.service import formats
from fpscan.service.storage.loader import input_formats


def test_every_surface_offers_the_registrys_formats(shared_api, tmp_path):
    from fpscan.clients.cli import recon as cli_recon
    from fpscan.clients.cli import unmix as cli_unmix

    uploads = [f.name for f in formats.FORMATS.values() if f.upload]
    assert uploads == ["npy", "kwave-hdf5", "kwave-mat", "fpscan", "ipasc"]  # what users may upload
    listed = shared_api.get("/api/datasets/formats").json()
    assert listed == [{"name": n, "title": formats.FORMATS[n].title, "wavelengths": formats.FORMATS[n].wavelengths}
                      for n in uploads]
    openapi = shared_api.get("/openapi.json").json()
    form = next(s for name, s in openapi["components"]["schemas"].items() if name.startswith("Body_upload_dataset"))
    assert form["properties"]["format"]["enum"] == uploads
    # a format the registry does not offer to uploads is refused at the door, naming the choices
    path = tmp_path / "x.npy"
    path.write_bytes(b"\x93NUMPY")
    with open(path, "rb") as fh:
        r = shared_api.post("/api/datasets", data={"format": "dataset"}, files={"file": ("x.npy", fh)})
    assert r.status_code == 422 and all(n in r.text for n in uploads), r.text
    for module in (cli_recon, cli_unmix):
        parser = argparse.ArgumentParser()
        module.add_arguments(parser)
        action = next(a for a in parser._actions if a.dest == "format")
        assert list(action.choices) == list(input_formats()) == list(formats.names(input=True))
        help_text = " ".join(parser.format_help().split())  # argparse wraps lines
        for name in input_formats():  # each choice explained by its title
            assert f"{name} = {' '.join(formats.FORMATS[name].title.split())}" in help_text, (module, name)
