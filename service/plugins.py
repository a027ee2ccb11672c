"""Plugins: the reconstruction methods and file formats fpscan finds through entry points.

Every method and format, fpscan's own included, is registered the one way: its distribution
declares it in an entry-point group (:data:`GROUPS`), and the registry loads the group when it
is first imported (``fpscan.service.recon.methods`` the group ``fpscan.methods``,
``fpscan.service.formats`` the group ``fpscan.formats``). fpscan declares its built-ins in its own
``pyproject.toml``; another package adds one by declaring it in its own (the model: xarray's
``xarray.backends`` entry points for its ``BackendEntrypoint`` s)::

    [project.entry-points."fpscan.methods"]
    toy = "fpscan_toy:METHOD"      # a fpscan.service.recon.methods.Method named "toy"

    [project.entry-points."fpscan.formats"]
    toy-text = "fpscan_toy:FORMAT"  # a fpscan.service.formats.Format named "toy-text"

An entry point's name is the method's or format's name; it points at the object (a ``Method``
or a ``Format``), which the registry registers. fpscan's own are loaded first, then those of
other distributions in the order Python finds them; the lists of choices are ordered by the
objects themselves (``Method.order``, ``Format.rank``), not by their entry points.

A plugin that fails (its import raises, it names no object of the right kind, or the registry
refuses it) is left out: the failure is logged once per process as a warning of the logger
``fpscan.plugins`` naming the entry point, its group and distribution, and kept in
:func:`failures`; the methods and formats that loaded serve as before.
"""
from __future__ import annotations

import logging
from collections.abc import Callable
from importlib import metadata
from typing import Any

__all__ = ["GROUPS", "DISTRIBUTION", "entry_points", "load_group", "failures", "put_in_order"]

#: the entry-point groups: methods (``fpscan.service.recon.methods.Method``), formats
#: (``fpscan.service.formats.Format``)
GROUPS = ("fpscan.methods", "fpscan.formats")
#: the distribution that declares the built-ins
DISTRIBUTION = "fpscan"

_log = logging.getLogger("fpscan.plugins")
#: (group, entry point name, distribution) -> the reason it failed; each reported once
_FAILED: dict[tuple[str, str, str], str] = {}


def entry_points(group: str) -> list[metadata.EntryPoint]:
    """The entry points of ``group``: fpscan's own first (in its metadata's order), then those
    of other distributions (in the order Python finds them on ``sys.path``).

    Parameters
    ----------
    group : str
        One of :data:`GROUPS`.

    Returns
    -------
    list of importlib.metadata.EntryPoint

    Raises
    ------
    RuntimeError
        fpscan's own distribution is installed without the group (installed from an older
        checkout: ``pip install -e .`` again).

    Examples
    --------
    >>> from fpscan.service.plugins import entry_points
    >>> sorted(ep.name for ep in entry_points("fpscan.methods") if ep.dist.name == "fpscan")
    ['cubic', 'kwave', 'linear', 'nearest', 'nedner', 'ner', 'tv']
    >>> next(ep for ep in entry_points("fpscan.formats") if ep.name == "npy").value
    'fpscan.service.formats.npy:FORMAT'
    """
    found = list(metadata.entry_points(group=group))

    def dist_name(ep: metadata.EntryPoint) -> str:
        return ep.dist.name if ep.dist is not None else ""

    own = [ep for ep in found if dist_name(ep) == DISTRIBUTION]
    if not own:
        raise RuntimeError(f"fpscan's installed metadata declares no {group} entry points: it was installed "
                           "from an older checkout; install it again (pip install -e .)")
    return own + [ep for ep in found if dist_name(ep) != DISTRIBUTION]


def load_group(group: str, kind: type, register: Callable[[Any], Any]) -> list[str]:
    """Load every entry point of ``group`` and register its object: the one registration path
    of methods and formats (module docstring).

    Parameters
    ----------
    group : str
        One of :data:`GROUPS`.
    kind : type
        The class each entry point's object must be (``Method``, ``Format``) with a ``name``
        equal to the entry point's.
    register : callable
        ``register(obj)``: the registry's; a ValueError it raises leaves the plugin out.

    Returns
    -------
    list of str
        The names registered, in order.

    Raises
    ------
    RuntimeError
        As :func:`entry_points` (fpscan's own metadata lacks the group). A plugin's own
        failure is never raised: it is reported (:func:`failures`).
    """
    done = []
    for ep in entry_points(group):
        try:
            obj = ep.load()
            if not isinstance(obj, kind):
                raise TypeError(f"{ep.value} is not a {kind.__name__}")
            if getattr(obj, "name", None) != ep.name:
                raise ValueError(f"{ep.value} is named {getattr(obj, 'name', None)!r}, its entry point {ep.name!r}")
            register(obj)
        except Exception as exc:  # any failure of a plugin's import or declaration leaves it out
            _report(group, ep, exc)
            continue
        done.append(ep.name)
    return done


def put_in_order(registry: dict[str, Any], name: str, obj: Any, position: Callable[[Any], int]) -> None:
    """Put ``obj`` into ``registry`` under ``name`` (replacing one of that name) and keep the
    registry in list order: by ``position(obj)``, entries of one position in registration order
    (the methods' ``Method.order``, the formats' ``Format.rank``).

    Parameters
    ----------
    registry : dict
        Name -> object, in list order.
    name : str
    obj : object
    position : callable
        ``position(obj) -> int``, smaller first.

    Examples
    --------
    >>> from fpscan.service.plugins import put_in_order
    >>> reg = {"b": 20, "d": 40}
    >>> put_in_order(reg, "c", 30, lambda v: v)
    >>> list(reg)
    ['b', 'c', 'd']
    """
    registry[name] = obj
    ordered = sorted(registry.items(), key=lambda item: position(item[1]))
    registry.clear()
    registry.update(ordered)


def _report(group: str, ep: metadata.EntryPoint, exc: BaseException) -> None:
    """Keep and log (once per process) the failure of the entry point ``ep`` of ``group``."""
    dist = ep.dist.name if ep.dist is not None else "?"
    key = (group, ep.name, dist)
    if key in _FAILED:
        return
    _FAILED[key] = f"{type(exc).__name__}: {exc}"
    _log.warning("fpscan: plugin %r (%s, from %s) failed to load and is left out: %s", ep.name, group, dist,
                 _FAILED[key])


def failures() -> dict[str, str]:
    """The plugins that failed to load in this process.

    Returns
    -------
    dict
        ``"<group>:<name> (<distribution>)"`` -> the reason (``"ModuleNotFoundError: ..."``),
        empty when every plugin loaded.

    Examples
    --------
    >>> import fpscan.service.formats, fpscan.service.recon.methods
    >>> from fpscan.service.plugins import failures
    >>> failures()  # fpscan's own load
    {}
    """
    return {f"{g}:{n} ({d})": why for (g, n, d), why in _FAILED.items()}
