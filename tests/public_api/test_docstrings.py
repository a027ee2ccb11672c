"""numpy-style docstrings on the public API of ``driver.physics``, ``service.metrics``,
``service.plans``, ``service.recon`` and ``clients.http`` (issue 21.5): every public function
and class has the sections that apply (Parameters with shapes and SI units, Returns, Examples;
Attributes for classes), and every Examples block runs here as a doctest."""
from __future__ import annotations

import doctest
import importlib
import inspect

import pytest

MODULES = [
    "driver.physics.axes", "driver.physics.balls", "driver.physics.fast_lengths", "driver.physics.fft_engine",
    "driver.physics.forward",
    "driver.physics.lateral",
    "driver.physics.nufft", "driver.physics.nufft_plans", "driver.physics.spectra", "driver.physics.weights",
    "service.metrics.correlation", "service.metrics.curves", "service.metrics.projections",
    "service.metrics.resolution", "service.metrics.roi", "service.metrics.sharpness",
    "service.plans.angular", "service.plans.grids", "service.plans.kinds", "service.plans.lattice",
    "service.plans.mask", "service.plans.ordering", "service.plans.plan", "service.plans.preview",
    "service.recon.checks", "service.recon.dataset", "service.recon.kwave", "service.recon.operator",
    "service.recon.planar", "service.recon.reconstruction", "service.recon.unmix", "service.recon.warmup",
    "service.recon.methods", "service.recon.methods.options", "service.recon.methods.ner",
    "service.recon.methods.nedner", "service.recon.methods.interp", "service.recon.methods.kwave",
    "service.recon.methods.tv", "service.recon.tv", "service.pipeline",
    "clients.http.client", "clients.http.async_client", "clients.http.calls", "clients.http.transport",
    "clients.http.waiting", "clients.http.errors", "clients.http.models", "clients.http.endpoints.server",
    "clients.http.endpoints.plans", "clients.http.endpoints.scans", "clients.http.endpoints.datasets",
    "clients.http.endpoints.reconstructions", "clients.http.endpoints.jobs",
]

#: Public classes whose docstring is text a user reads elsewhere, not a numpy docstring: a mask
#: kind's parameter model is the kind's one-line description (``MaskKind.description``, shown by
#: ``fpscan plan --help`` and ``/api/plans/kinds``). Their examples live in the module docstring
#: (counted by ``test_examples_run``).
SERVED_DOCSTRINGS = {
    "service.plans.kinds": {"FullParams", "EquispacedParams", "HexagonalParams", "RandomParams",
                            "PoissonParams", "PointsParams", "EquiangularParams", "EquisteradianParams"},
}


def _sections(doc: str) -> set[str]:
    """Names of the numpy sections of ``doc`` (a title line underlined with dashes)."""
    lines = inspect.cleandoc(doc).splitlines()
    return {lines[i].strip() for i in range(len(lines) - 1)
            if lines[i].strip() and set(lines[i + 1].strip()) == {"-"}
            and len(lines[i + 1].strip()) == len(lines[i].strip())}


def _public_objects(module_name: str):
    module = importlib.import_module(module_name)
    for name in module.__all__:
        obj = getattr(module, name)
        # __wrapped__: functools.lru_cache and numba's dispatchers
        if inspect.isfunction(obj) or inspect.isclass(obj) or callable(getattr(obj, "__wrapped__", None)):
            yield name, obj


def _wanted(obj) -> set[str]:
    if inspect.isclass(obj):
        return {"Attributes", "Examples"}
    fn = getattr(obj, "__wrapped__", obj)
    sig = inspect.signature(fn)
    wanted = {"Examples"}
    if sig.parameters:
        wanted.add("Parameters")
    if sig.return_annotation not in ("None", None):
        wanted.add("Returns")
    return wanted


@pytest.mark.parametrize("module_name", MODULES)
def test_public_definitions_have_numpy_sections(module_name):
    objects = list(_public_objects(module_name))
    assert objects, module_name
    served = SERVED_DOCSTRINGS.get(module_name, set())
    lacking = {name: sorted(_wanted(obj) - _sections(obj.__doc__ or "")) for name, obj in objects
               if name not in served}
    lacking = {name: missing for name, missing in lacking.items() if missing}
    assert not lacking, f"{module_name}: sections missing {lacking}"


@pytest.mark.parametrize("module_name", MODULES)
def test_examples_run(module_name):
    module = importlib.import_module(module_name)
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.failed == 0, result
    assert result.attempted >= 2 * len(list(_public_objects(module_name))), result


def test_the_section_reader_sees_sections():
    doc = """Summary.

    Parameters
    ----------
    x : float

    Returns
    -------
    float
    """
    assert _sections(doc) == {"Parameters", "Returns"}
    assert _sections("Parameters: none\n") == set()
