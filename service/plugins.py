"""Plugins: the reconstruction methods and file formats other packages add through entry points.

fpscan's own methods and formats are registered in code, when their registry is first imported
(``fpscan.service.recon.methods``, ``fpscan.service.formats``: the model is xarray's
``BACKEND_ENTRYPOINTS``). Another package adds one by declaring it in an entry-point group
(:data:`GROUPS`) of its own ``pyproject.toml`` (the model: xarray's ``xarray.backends`` entry
points for its ``BackendEntrypoint`` s)::

    [project.entry-points."fpscan.methods"]
    das = "fpscan_das:METHOD"      # a fpscan.plugins.Method named "das"

    [project.entry-points."fpscan.formats"]
    toy-text = "fpscan_toy:FORMAT"  # a fpscan.plugins.Format named "toy-text"

An entry point's name is the method's or format's name; it points at the object (a ``Method``
or a ``Format``), which the registry registers. The entry points are read lazily: a registry
(:class:`PluginRegistry`) loads its group the first time it is read (a lookup, a listing), not
when it is imported, so importing fpscan never imports another package's code. The lists of
choices are ordered by the objects themselves (``Method.order``, ``Format.rank``), not by their
entry points. The public names a plugin builds on are :mod:`fpscan.plugins`'.

A plugin that fails (its import raises, it names no object of the right kind, or the registry
refuses it) is left out: the failure is logged once per process as a warning of the logger
``fpscan.plugins`` naming the entry point, its group and distribution, and kept in
:func:`failures`; the methods and formats that loaded serve as before.
"""
from __future__ import annotations

import logging
from collections.abc import Callable
from importlib import metadata
from typing import Any, Generic, TypeVar

__all__ = ["GROUPS", "DISTRIBUTION", "entry_points", "load_group", "failures", "put_in_order", "PluginRegistry"]

#: the entry-point groups: methods (``fpscan.service.recon.methods.Method``), formats
#: (``fpscan.service.formats.Format``)
GROUPS = ("fpscan.methods", "fpscan.formats")
#: fpscan's own distribution (its methods and formats are registered in code; an entry point it
#: declared in an older release is skipped)
DISTRIBUTION = "fpscan"

_log = logging.getLogger("fpscan.plugins")
#: a registry's object type (``Method``, ``Format``)
T = TypeVar("T")
#: (group, entry point name, distribution) -> the reason it failed; each reported once
_FAILED: dict[tuple[str, str, str], str] = {}


def entry_points(group: str) -> list[metadata.EntryPoint]:
    """The entry points of ``group`` that other distributions declare, in the order Python
    finds them on ``sys.path`` (fpscan's own methods and formats are registered in code).

    Parameters
    ----------
    group : str
        One of :data:`GROUPS`.

    Returns
    -------
    list of importlib.metadata.EntryPoint

    Examples
    --------
    >>> from fpscan.service.plugins import entry_points
    >>> [ep for ep in entry_points("fpscan.methods") if ep.dist is not None and ep.dist.name == "fpscan"]
    []
    """
    found = list(metadata.entry_points(group=group))
    return [ep for ep in found if (ep.dist.name if ep.dist is not None else "") != DISTRIBUTION]


def load_group(group: str, kind: type, register: Callable[[Any], Any]) -> list[str]:
    """Load every entry point of ``group`` and register its object: the one registration path
    of the plugins' methods and formats (module docstring).

    An entry point whose module is being imported at that moment (a plugin module that reads
    the other registry while it is imported: that registry's first read loads its group, which
    names the same module) is registered once the outermost load is done, instead of failing on
    the half-imported module.

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
        The names registered, in order (those of a deferred entry point come after, at the end
        of the outermost load).

    Notes
    -----
    A plugin's own failure is never raised: it is reported (:func:`failures`).
    """
    done = []
    _LOADING.append(group)
    try:
        for ep in entry_points(group):
            if _importing(ep.module):
                _DEFERRED.append((group, ep, kind, register))
                continue
            if _load_one(group, ep, kind, register):
                done.append(ep.name)
    finally:
        _LOADING.pop()
    while not _LOADING and _DEFERRED:  # the outermost load: the modules it waited for are imported now
        deferred_group, ep, deferred_kind, deferred_register = _DEFERRED.pop(0)
        if _load_one(deferred_group, ep, deferred_kind, deferred_register) and deferred_group == group:
            done.append(ep.name)
    return done


#: the groups being loaded (nested: a plugin module's import reads the other registry)
_LOADING: list[str] = []
#: entry points whose module was being imported when their group loaded: registered after
_DEFERRED: list[tuple[str, metadata.EntryPoint, type, Callable[[Any], Any]]] = []


def _importing(module: str) -> bool:
    """Whether ``module`` is being imported now (in ``sys.modules``, its import not finished)."""
    import sys

    found = sys.modules.get(module)
    return found is not None and bool(getattr(getattr(found, "__spec__", None), "_initializing", False))


def _load_one(group: str, ep: metadata.EntryPoint, kind: type, register: Callable[[Any], Any]) -> bool:
    """Load and register one entry point's object; a failure is reported (:func:`failures`) and
    gives False."""
    try:
        obj = ep.load()
        if not isinstance(obj, kind):
            raise TypeError(f"{ep.value} is not a {kind.__name__}")
        if getattr(obj, "name", None) != ep.name:
            raise ValueError(f"{ep.value} is named {getattr(obj, 'name', None)!r}, its entry point {ep.name!r}")
        register(obj)
    except Exception as exc:  # any failure of a plugin's import or declaration leaves it out
        _report(group, ep, exc)
        return False
    return True


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


class PluginRegistry(dict[str, T], Generic[T]):
    """A registry (name -> object, in list order) that loads the plugins of its entry-point group
    the first time it is read: ``[name]``, ``in``, iteration, ``len``, ``get``, ``keys``,
    ``values``, ``items``. Built-ins are put in before it is armed (:meth:`arm`), without
    loading anything.

    Parameters
    ----------
    group : str
        One of :data:`GROUPS`.

    Examples
    --------
    >>> from fpscan.service.plugins import PluginRegistry
    >>> reg = PluginRegistry("fpscan.methods")
    >>> reg["builtin"] = 1
    >>> reg.arm(int, lambda obj: None)  # no entry point of another package is read yet
    >>> reg.loaded, list(reg), reg.loaded
    (False, ['builtin'], True)
    """

    def __init__(self, group: str) -> None:
        super().__init__()
        self.group = group
        self._pending: tuple[type, Callable[[Any], Any]] | None = None
        self.loaded = False

    def arm(self, kind: type, register: Callable[[Any], Any]) -> None:
        """Load the group's plugins on the first read, each checked to be a ``kind`` and
        registered by ``register`` (:func:`load_group`)."""
        self._pending = (kind, register)

    def _load(self) -> None:
        if self._pending is None:
            return
        kind, register = self._pending
        self._pending = None  # first: a plugin's registration reads the registry
        load_group(self.group, kind, register)
        self.loaded = True

    def __getitem__(self, key: Any) -> T:
        self._load()
        return super().__getitem__(key)

    def __contains__(self, key: object) -> bool:
        self._load()
        return super().__contains__(key)

    def __iter__(self) -> Any:
        self._load()
        return super().__iter__()

    def __len__(self) -> int:
        self._load()
        return super().__len__()

    def __repr__(self) -> str:
        """One line: the group and the names registered (after loading the plugins).

        Examples
        --------
        >>> from fpscan.service.plugins import PluginRegistry
        >>> reg = PluginRegistry("fpscan.methods")
        >>> reg["builtin"] = 1
        >>> reg
        PluginRegistry(fpscan.methods: 1 entry: builtin)
        """
        from fpscan.wire.brief import one_line

        self._load()
        n = len(self)
        return one_line(f"PluginRegistry({self.group}: {n} entr{'y' if n == 1 else 'ies'}: {', '.join(self)})")

    def get(self, key: Any, default: Any = None) -> Any:
        """``dict.get``, after loading the plugins."""
        self._load()
        return super().get(key, default)

    def keys(self) -> Any:
        """``dict.keys``, after loading the plugins."""
        self._load()
        return super().keys()

    def values(self) -> Any:
        """``dict.values``, after loading the plugins."""
        self._load()
        return super().values()

    def items(self) -> Any:
        """``dict.items``, after loading the plugins."""
        self._load()
        return super().items()
