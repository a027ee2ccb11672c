"""numpy-style docstrings.

The modules of :data:`MODULES` (``fpscan.physics``, ``fpscan.service.metrics``, ``fpscan.service.plans``,
``fpscan.service.recon``, ``fpscan.clients.http``, ...): every public function and class has the sections
that apply (Parameters with shapes and SI units, Returns, Examples; Attributes for classes).
Every example of every module (found on disk, :func:`example_modules`) runs here as a
doctest. Every public module of ``service``, ``driver``, ``clients`` and ``fpscan`` (found on
disk, :func:`public_modules`) says what it is, and at least :data:`COVERAGE` of their public definitions have their numpy sections."""
from __future__ import annotations

import doctest
import importlib
import inspect

import pytest

MODULES = [
    "fpscan.physics.axes", "fpscan.physics.balls", "fpscan.physics.fast_lengths", "fpscan.physics.fft_engine",
    "fpscan.physics.forward",
    "fpscan.physics.lateral",
    "fpscan.physics.nufft", "fpscan.physics.nufft_plans", "fpscan.physics.spectra", "fpscan.physics.weights",
    "fpscan.service.metrics.correlation", "fpscan.service.metrics.curves", "fpscan.service.metrics.projections",
    "fpscan.service.metrics.resolution", "fpscan.service.metrics.roi", "fpscan.service.metrics.sharpness",
    "fpscan.service.plans.angular", "fpscan.service.plans.grids", "fpscan.service.plans.kinds", "fpscan.service.plans.lattice",
    "fpscan.service.plans.mask", "fpscan.service.plans.ordering", "fpscan.service.plans.plan", "fpscan.service.plans.preview",
    "fpscan.service.recon.checks", "fpscan.service.recon.memory", "fpscan.service.recon.dataset", "fpscan.service.recon.kwave", "fpscan.service.recon.operator",
    "fpscan.service.recon.planar", "fpscan.service.recon.reconstruction", "fpscan.service.recon.unmix", "fpscan.service.recon.warmup",
    "fpscan.service.recon.methods.registry", "fpscan.service.recon.methods.render", "fpscan.service.recon.methods.work",
    "fpscan.service.recon.methods.options", "fpscan.service.recon.methods.ner",
    "fpscan.service.recon.methods.nedner", "fpscan.service.recon.methods.interp", "fpscan.service.recon.methods.kwave",
    "fpscan.service.recon.methods.tv", "fpscan.service.recon.tv.reconstruct", "fpscan.service.recon.tv.grid",
    "fpscan.service.recon.tv.problem", "fpscan.service.recon.tv.preconditioner", "fpscan.service.recon.tv.geometry",
    "fpscan.service.recon.tv.lam", "fpscan.service.recon.tv.fista", "fpscan.service.recon.tv.prox",
    "fpscan.service.recon.tv.stopping", "fpscan.service.recon.tv.stores", "fpscan.service.recon.tv.progress",
    "fpscan.service.recon.tv.result", "fpscan.service.recon.tv.kernels", "fpscan.service.pipeline",
    "fpscan.clients.http.client", "fpscan.clients.http.async_client", "fpscan.clients.http.calls", "fpscan.clients.http.transport",
    "fpscan.clients.http.waiting", "fpscan.clients.http.errors", "fpscan.clients.http.models", "fpscan.clients.http.endpoints.server",
    "fpscan.clients.http.endpoints.plans", "fpscan.clients.http.endpoints.scans", "fpscan.clients.http.endpoints.datasets",
    "fpscan.clients.http.endpoints.reconstructions", "fpscan.clients.http.endpoints.jobs",
]

#: Public classes whose docstring is text a user reads elsewhere, not a numpy docstring: a mask
#: kind's parameter model is the kind's one-line description (``MaskKind.description``, shown by
#: ``fpscan plan --help`` and ``/api/plans/kinds``). Their examples live in the module docstring
#: (counted by ``test_examples_run``).
SERVED_DOCSTRINGS = {
    "fpscan.service.plans.kinds": {"FullParams", "EquispacedParams", "HexagonalParams", "RandomParams",
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


# -- every public module of service, driver, clients and fpscan -----------------

#: the packages whose public modules the coverage test reads
PACKAGES = ("fpscan",)
#: the share of public definitions that must have their numpy sections
COVERAGE = 0.90


def public_modules() -> list[str]:
    """Every module of :data:`PACKAGES` whose dotted name has no part starting with ``_``
    (``__init__`` modules count as their package), found on disk: a module added later is in."""
    import pkgutil

    found = []
    for package in PACKAGES:
        root = importlib.import_module(package)
        found.append(package)
        for info in pkgutil.walk_packages(root.__path__, prefix=package + ".", onerror=lambda _name: None):
            if not any(part.startswith("_") for part in info.name.split(".")):
                found.append(info.name)
    return sorted(found)


def example_modules() -> list[str]:
    """Every module of :data:`PACKAGES` whose source holds a doctest prompt (``>>>``), found on
    disk (private modules included, ``__main__`` modules not: importing one runs it): a module
    that gains examples is in, and each of :data:`MODULES` is in whether or not it has any."""
    from tests.source_tree import module_files

    found = set(MODULES)
    for package in PACKAGES:
        for name, path in module_files(package):
            if path.name == "__main__.py" or ">>>" not in path.read_text(encoding="utf-8"):
                continue
            found.add(name)
    return sorted(found)


@pytest.mark.parametrize("module_name", example_modules())
def test_examples_run(module_name):
    """Every example runs (found on disk, not listed); the modules of :data:`MODULES` hold
    at least two per public definition."""
    module = importlib.import_module(module_name)
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.failed == 0, result
    assert result.attempted > 0, f"{module_name}: its >>> lines are in no docstring doctest finds"
    if module_name in MODULES:
        assert result.attempted >= 2 * len(list(_public_objects(module_name))), result


def _defined_here(module) -> list[tuple[str, object]]:
    """A module's public definitions: its ``__all__`` (functions and classes), else the
    functions and classes it defines whose names do not start with ``_``."""
    names = getattr(module, "__all__", None)
    if names is None:
        names = [n for n, v in vars(module).items() if not n.startswith("_")
                 and (inspect.isfunction(v) or inspect.isclass(v)) and getattr(v, "__module__", None) == module.__name__]
    out = []
    for name in names:
        obj = getattr(module, name, None)
        if inspect.isfunction(obj) or inspect.isclass(obj) or callable(getattr(obj, "__wrapped__", None)):
            out.append((name, obj))
    return out


def _sections_wanted(obj) -> set[str]:
    """The numpy sections a public definition needs: a class, Attributes or Parameters (either
    one); a function, Parameters when it takes any and Returns when it returns something."""
    if inspect.isclass(obj):
        return set()
    fn = getattr(obj, "__wrapped__", obj)
    try:
        sig = inspect.signature(fn)
    except (TypeError, ValueError):
        return set()
    wanted = set()
    if sig.parameters:
        wanted.add("Parameters")
    if sig.return_annotation not in ("None", None, inspect.Signature.empty):
        wanted.add("Returns")
    return wanted


def _route_handlers() -> set[int]:
    """The functions the HTTP API serves as endpoints: their docstring is the endpoint's
    description in the OpenAPI document (``/docs``), text a client reads, not a numpy docstring."""
    import pkgutil

    import fpscan.service.api

    ids = set()
    for info in pkgutil.iter_modules(fpscan.service.api.__path__):
        router = getattr(importlib.import_module(f"fpscan.service.api.{info.name}"), "router", None)
        ids |= {id(getattr(route, "endpoint", None)) for route in getattr(router, "routes", ())}
    return ids


def documented(obj) -> bool:
    """True when ``obj``'s docstring has the numpy sections it needs (:func:`_sections_wanted`);
    a class: an Attributes or Parameters section, or a pydantic model whose every field has its
    description (the JSON schema's, what the API, CLI and web page show)."""
    have = _sections(obj.__doc__ or "")
    if inspect.isclass(obj):
        fields = getattr(obj, "model_fields", None)
        if fields and all(f.description for f in fields.values()):
            return True
        return bool(have & {"Attributes", "Parameters"})
    return _sections_wanted(obj) <= have


def _counted_in(obj, module_name: str) -> bool:
    """A definition counts in the module that defines it, or, when that module is private
    (a part of its dotted name starts with ``_``), in the public module that exports it."""
    home = getattr(obj, "__module__", None) or ""
    return home == module_name or (any(p.startswith("_") for p in home.split("."))
                                   and home.startswith(module_name + "."))


def coverage() -> tuple[int, int, dict[str, list[str]]]:
    """(documented, public definitions, module -> the undocumented names) over
    :func:`public_modules`; the API's endpoint functions (:func:`_route_handlers`) and
    :data:`SERVED_DOCSTRINGS` are not counted."""
    done = total = 0
    lacking: dict[str, list[str]] = {}
    seen: set[int] = set()
    served_ids = _route_handlers()
    for name in public_modules():
        module = importlib.import_module(name)
        served = SERVED_DOCSTRINGS.get(name, set())
        for obj_name, obj in _defined_here(module):
            if (obj_name in served or id(obj) in seen or id(obj) in served_ids
                    or not _counted_in(obj, name)):
                continue
            seen.add(id(obj))
            total += 1
            if documented(obj):
                done += 1
            else:
                lacking.setdefault(name, []).append(obj_name)
    return done, total, lacking


@pytest.mark.parametrize("module_name", public_modules())
def test_every_public_module_says_what_it_is(module_name):
    module = importlib.import_module(module_name)
    assert (module.__doc__ or "").strip(), f"{module_name} has no module docstring"


def test_most_public_definitions_have_their_numpy_sections():
    done, total, lacking = coverage()
    worst = sorted(lacking.items(), key=lambda kv: -len(kv[1]))[:15]
    assert total > 400 and done >= COVERAGE * total, (
        f"{done}/{total} = {done / total:.0%} of public definitions have their numpy sections "
        f"(want {COVERAGE:.0%}); most lacking: " + "; ".join(f"{m}: {', '.join(n)}" for m, n in worst))
