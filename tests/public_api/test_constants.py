"""Each physical default is stated once, in ``fpscan.constants``. The oracle is
the source itself: no other module of the product spells the default speed of sound or an
end of the autofocus interval as a number (an AST walk, so comments and prose don't count),
and the values the library, the CLI and the HTTP model offer are the constants."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

from fpscan import constants

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("driver", "service", "clients", "fpscan")  # fpscan/: the package root, physics, wire (its links to the three folders are not followed)
SPELLED_ONCE = {constants.C_DEFAULT, *constants.C_AUTOFOCUS_RANGE}


def _numbers(path: Path):
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    for node in ast.walk(tree):
        if (isinstance(node, ast.Constant) and isinstance(node.value, (int, float))
                and not isinstance(node.value, bool) and node.value in SPELLED_ONCE):
            yield node.lineno, node.value


def test_the_speed_of_sound_defaults_are_spelled_only_in_the_constants_module():
    found = [f"{p.relative_to(ROOT)}:{line}: {value!r}"
             for pkg in PACKAGES for p in sorted((ROOT / pkg).rglob("*.py"))
             if p != ROOT / "fpscan" / "constants.py" for line, value in _numbers(p)]
    assert not found, "use fpscan.constants instead of:\n" + "\n".join(found)


def test_the_library_the_plan_contract_and_the_http_model_take_the_constants():
    import inspect

    from fpscan.service.api.models import PARAMS_MODELS
    from fpscan.service.autofocus import autofocus
    from fpscan.service.plans.plan import Acquisition
    from fpscan.service.recon.planar import reconstruct_grid, reconstruct_points

    assert all(inspect.signature(f).parameters["c"].default == constants.C_DEFAULT
               for f in (reconstruct_grid, reconstruct_points))
    assert inspect.signature(autofocus).parameters["sound_speed_range"].default == constants.C_AUTOFOCUS_RANGE
    assert Acquisition.model_fields["sound_speed"].default == constants.C_DEFAULT
    # the speed of sound's names in every method's request options: sound_speed / sound_speed_range
    for model in PARAMS_MODELS.values():
        schema = model.model_json_schema()["properties"]["sound_speed_range"]
        ends = [item for item in schema["anyOf"] if item.get("type") == "array"][0]["prefixItems"]
        assert all((e["minimum"], e["maximum"]) == constants.C_AUTOFOCUS_LIMITS for e in ends)


@pytest.mark.parametrize("c, force, ok", [(constants.C_PLAUSIBLE[1], False, True),
                                          (constants.C_PLAUSIBLE[1] + 1, False, False),
                                          (constants.C_PLAUSIBLE[1] + 1, True, True),
                                          (constants.C_LIMITS[1], True, True),
                                          (constants.C_LIMITS[1] + 1, True, False),
                                          (constants.C_LIMITS[0], True, False)])
def test_a_forced_speed_stays_within_the_limits_in_the_library_as_over_http(c, force, ok):
    from pydantic import ValidationError

    from fpscan.driver.units import RefusedInput, check_speeds
    from fpscan.service.api.models import PARAMS_MODELS

    if ok:
        check_speeds(sound_speed=c, force=force)
        PARAMS_MODELS["ner"](sound_speed=c, force=force)
    else:
        with pytest.raises(RefusedInput):
            check_speeds(sound_speed=c, force=force)
        with pytest.raises(ValidationError):
            PARAMS_MODELS["ner"](sound_speed=c, force=force)
