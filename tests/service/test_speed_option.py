"""The speed of sound is one typed option of the registry:
``fpscan.service.recon.methods.options.SpeedOptions`` (unit, bounds, default) and every surface reads
it — the HTTP request model, ``GET /api/reconstructions/methods`` (the web page's fields and
labels), the upload form, ``fpscan recon``'s flags; no source file of the product types the
plausible range again.

Oracles: ``fpscan.constants`` (the numbers), the served OpenAPI document and method list of a
real server, ``fpscan recon --help`` as a user runs it, and the source tree itself."""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

from fpscan.clients.processes import clean_env
from fpscan.constants import C_AUTOFOCUS_RANGE, C_LIMITS, C_PLAUSIBLE
from fpscan.service.recon.methods.options import SpeedOptions, plausible_speeds, speed_schema

REPO = Path(__file__).resolve().parents[2]
PLAUSIBLE = f"{C_PLAUSIBLE[0]:g}-{C_PLAUSIBLE[1]:g}"


def test_the_option_states_its_unit_bounds_and_default():
    fields = SpeedOptions.model_fields
    assert list(fields) == ["sound_speed", "sound_speed_range", "force"]
    assert {fields[n].json_schema_extra["unit"] for n in ("sound_speed", "sound_speed_range")} == {"m/s"}
    assert plausible_speeds() == PLAUSIBLE and PLAUSIBLE in fields["force"].description
    assert f"{C_LIMITS[0]:g}-{C_LIMITS[1]:g}" in fields["sound_speed"].description
    assert f"{C_AUTOFOCUS_RANGE[0]:g}-{C_AUTOFOCUS_RANGE[1]:g}" in fields["sound_speed_range"].description
    number = speed_schema()["anyOf"][0]
    assert (number["minimum"], number["maximum"]) == C_PLAUSIBLE


def test_every_surface_reads_the_one_option(shared_api):
    listed = shared_api.get("/api/reconstructions/methods").json()
    for m in listed:
        speed = next(o for o in m["options"] if o["name"] == "sound_speed")
        assert speed["value_schema"] == speed_schema() and speed["description"] == SpeedOptions.model_fields[
            "sound_speed"].description, m["name"]
    openapi = shared_api.get("/openapi.json").json()
    schemas = openapi["components"]["schemas"]
    for name in [n for n in schemas if n.startswith("ReconRequest") and n != "ReconRequestDefaultMethod"]:
        params = schemas[schemas[name]["properties"]["params"]["$ref"].rsplit("/", 1)[1]]  # each method's options
        assert params["properties"]["sound_speed"]["description"] == SpeedOptions.model_fields["sound_speed"].description
        assert params["properties"]["force"]["description"] == SpeedOptions.model_fields["force"].description
    upload = next(s for name, s in schemas.items() if name.startswith("Body_upload_dataset"))
    assert PLAUSIBLE in upload["properties"]["sound_speed"]["description"]
    assert upload["properties"]["force"]["description"] == SpeedOptions.model_fields["force"].description
    helped = subprocess.run([sys.executable, "-m", "fpscan", "recon", "--help"], capture_output=True, text=True,
                            timeout=120, env=clean_env(COLUMNS="400"))
    assert helped.returncode == 0, helped.stderr
    force = next(line for line in helped.stdout.splitlines() if line.strip().startswith("--force"))
    assert PLAUSIBLE in force, force


def test_no_product_file_types_the_plausible_range_again():
    pattern = re.compile(rf"{C_PLAUSIBLE[0]:g}\s*(?:-|–|to)\s*{C_PLAUSIBLE[1]:g}")
    owner = REPO / "service" / "recon" / "methods" / "options.py"  # its docstring examples show the text
    typed = []
    for root in ("service", "clients", "fpscan"):
        for path in (REPO / root).rglob("*"):
            if path.suffix in (".py", ".js", ".html") and "__pycache__" not in path.parts and path != owner:
                for k, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
                    if pattern.search(line):
                        typed.append(f"{path.relative_to(REPO)}:{k}: {line.strip()}")
    assert not typed, "the plausible speeds typed again (read SpeedOptions / plausible_speeds):\n" + "\n".join(typed)
