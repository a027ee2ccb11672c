"""The registry of file formats (:mod:`fpscan.service.formats`): what a format declares
(:class:`Format`), the one place a file is opened and checked (:func:`open_source`), and
detection and loading by name or from the content.

A format's module, fpscan's own or a plugin's, builds its ``FORMAT = Format(...)`` from
this module's :class:`Format` and reads the file through the :class:`Source` its ``sniff``
and ``load`` are given; the package :mod:`fpscan.service.formats` re-exports every name of
:data:`__all__`.

A file is opened once per load: :func:`open_source` reads its first :data:`HEAD_BYTES`
bytes and, for an HDF5 file, opens it once read-only (``fpscan.driver.scanfile.open_readonly``:
SWMR only for a file a writer has open) and checks it there
(``fpscan.service.formats.untrusted.check_hdf5_file``: no external links, external storage or
virtual datasets, no dataset declaring more than ``max_bytes`` or more than it stores)
before any format's ``sniff`` or ``load`` sees it; a file HDF5 would open as an SWMR
reader (a writer has it open) is detected and loaded in a bounded child process
(``fpscan.service.formats.untrusted.read_bounded``). Those protections so hold for every format,
the registered ones and any added later, not per reader.
"""
from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, BinaryIO

from fpscan.driver.hdf5_checks import HDF5_SIGNATURE
from fpscan.service.plugins import PluginRegistry, put_in_order
from fpscan.service.recon.dataset import MAX_ELEMENTS

if TYPE_CHECKING:
    from pydantic import BaseModel

__all__ = ["Format", "Source", "FORMATS", "HEAD_BYTES", "MAX_BYTES", "UNREADABLE", "register", "unregister", "names",
           "open_source", "sniff", "detect", "describe", "load", "export_formats", "export_file"]

#: bytes of a file's start every ``sniff`` sees (:attr:`Source.head`): a MATLAB v7.3 MAT-file's
#: 512-byte header and the HDF5 signature behind it included
HEAD_BYTES = 1024
#: default bound on any one HDF5 dataset's declared bytes (``check_hdf5_file``)
MAX_BYTES = MAX_ELEMENTS * 8
#: where an HDF5 file's superblock may start in the files fpscan reads: at 0, or behind a
#: 512-byte user block (MATLAB's v7.3 MAT-files: their text header, then HDF5). HDF5 itself
#: looks at 0, 512, 1024, 2048, ...; fpscan opens only these two.
HDF5_OFFSETS = (0, 512)


def _hdf5_offset(head: bytes) -> int | None:
    """Where ``head`` (a file's first bytes) holds the HDF5 signature: 0, 512 (behind a
    user block: a MATLAB v7.3 MAT-file) or None (not HDF5)."""
    for offset in HDF5_OFFSETS:
        if head[offset:offset + 8] == HDF5_SIGNATURE:
            return offset
    return None


@dataclass
class Source:
    """A file opened once for detection and loading (made by :func:`open_source`).

    Attributes
    ----------
    path : pathlib.Path
        The file's name.
    head : bytes
        Its first :data:`HEAD_BYTES` bytes (fewer for a shorter file).
    h5 : h5py.File or None
        The read-only ``h5py.File`` (HDF5 files, already checked by
        ``fpscan.service.formats.untrusted.check_hdf5_file``), else None.
    fh : BinaryIO or None
        The open binary file positioned at 0 (other files), else None.
    """

    path: Path
    head: bytes
    h5: Any = None
    fh: BinaryIO | None = None

    @property
    def is_hdf5(self) -> bool:
        """True for an HDF5 file (signature at offset 0, or at 512 behind a user block:
        :data:`HDF5_OFFSETS`)."""
        return _hdf5_offset(self.head) is not None

    def attr(self, name: str) -> str:
        """The HDF5 root attribute ``name`` as text (``""`` when absent or not HDF5)."""
        if self.h5 is None:
            return ""
        v = self.h5.attrs.get(name)
        return v.decode() if isinstance(v, bytes) else str(v if v is not None else "")


@dataclass(frozen=True)
class Format:
    """One file format: one module of :mod:`fpscan.service.formats` declares it, the registry
    (:func:`register`) serves it.

    Attributes
    ----------
    name : str
        The name users give (``--format``, the upload's ``format`` field).
    title : str
        What a person reads (the web page's choices, the CLI help).
    container : {"hdf5", "file", "any"}
        ``"hdf5"``: the registry opens and checks the HDF5 file (``Source.h5``);
        ``"file"``: any other file (``Source.fh``, ``Source.head``); ``"any"``: either,
        by the file's signature (a format with an HDF5 and a plain variant: MATLAB's
        MAT-files, v7.3 and v5), its ``sniff`` and ``load`` seeing ``Source.h5`` or
        ``Source.fh``.
    sniff : callable or None
        ``sniff(source) -> bool``: cheap detection from ``source.head`` and, for HDF5,
        its root attributes and links (no data read); None: never detected (a format
        fpscan only writes).
    load : callable or None
        ``load(source, **options)``: the content (a ``GridDataset`` / ``PointDataset``
        for an input format). Options it does not take are ignored (``**_``); the
        registry passes ``max_bytes`` (the bound on any one array's declared bytes) with
        them, for a format that decodes arrays HDF5's checks do not see (MAT v5's zlib).
        None: no reader.
    write : callable or None
        ``write(path, obj)`` where the format has a writer.
    export_from : str or None
        The registered format whose files this one exports (``"result"``: a reconstruction's
        ``volume.h5``; ``"fpscan"``: a scan file); None: no export. Exports are offered by
        ``fpscan export`` (``--format``), ``GET /api/jobs/{id}/export/{name}``, the HTTP
        client's ``export`` and the web page's downloads: :func:`export_formats`.
    export : callable or None
        ``export(src_path, out_path) -> out_path``: writes the export of the file
        ``src_path`` (a file of ``export_from``) at ``out_path`` (a temporary sibling renamed
        into place); raises ValueError with the reason.
    suffix : str
        The ending of an export's default file name (``<stem><suffix>``, e.g. ``".ome.tif"``).
    media_type : str
        The export's HTTP ``Content-Type`` (a folder export is served as ``application/zip``).
    folder : bool
        The export is a folder (OME-Zarr): served zipped over HTTP, unpacked by the client.
    options : type or None
        Its load options: a pydantic model whose fields (type, range, unit, default) ``load``
        takes by name; the upload's fields, ``fpscan recon``'s flags and the web page's upload
        form are generated from them (``GET /api/formats``). None: it takes none.
    input : bool
        A reconstruction input (``fpscan recon --format``, ``load_dataset``).
    upload : bool
        Accepted by ``POST /api/datasets`` (the API's, the HTTP client's and the web
        page's choices: ``GET /api/datasets/formats``).
    wavelengths : bool
        May hold several excitation wavelengths: its ``load`` takes ``wavelength_index``
        (one of them) and ``all_wavelengths`` (a list, one per wavelength).
    refuse : str or None
        Not data to reconstruct: the reason :func:`fpscan.service.storage.loader.load_dataset`
        gives when the content is detected as this format.
    order : int
        Sniffing order, lowest first; the catch-all (any HDF5 array: ``kwave-hdf5``) last.
    rank : int
        Position in the lists of choices (:func:`names`, :func:`export_formats`), smallest
        first, formats of one rank in registration order; fpscan's own are 10..140, the
        default (1000) puts a plugin's after them.
    noun : str
        The format in a message (``"a NumPy .npy array"``; default ``"a <name> file"``).
    """

    name: str
    title: str
    container: str
    sniff: Callable[[Source], bool] | None = None
    load: Callable[..., Any] | None = None
    write: Callable[..., Any] | None = None
    export_from: str | None = None
    export: Callable[[Path, Path], Path] | None = None
    suffix: str = ""
    media_type: str = "application/octet-stream"
    folder: bool = False
    options: type[BaseModel] | None = None
    input: bool = False
    upload: bool = False
    wavelengths: bool = False
    refuse: str | None = None
    order: int = 50
    noun: str = ""
    rank: int = 1000

    def __repr__(self) -> str:
        """One line: the name, title, container and what it does (never its callables).

        Examples
        --------
        >>> from fpscan.service.formats import FORMATS
        >>> FORMATS["npy"]  # doctest: +ELLIPSIS
        Format(npy: 'NumPy array...', file, reads input, ...)
        """
        from fpscan.wire.brief import one_line

        does = [w for w, on in (("reads input", self.input and self.load is not None), ("uploads", self.upload),
                                ("writes", self.write is not None), ("exports", self.export is not None)) if on]
        return one_line(f"Format({self.name}: {self.title!r}, {self.container}{''.join(', ' + d for d in does)})")

    @property
    def what(self) -> str:
        """The format as a noun in a message: ``noun``, else ``"a <name> file"``."""
        return self.noun or f"a {self.name} file"


#: name -> format, every registered format (:func:`register`), in list order (:attr:`Format.rank`)
#: (fpscan's own, registered in code, and the plugins': entry points of ``fpscan.formats``, read on
#: the first lookup or listing)
FORMATS: PluginRegistry[Format] = PluginRegistry("fpscan.formats")


def register(fmt: Format) -> Format:
    """Add ``fmt`` to the registry (detection, loading, the lists of choices).

    Parameters
    ----------
    fmt : Format
        The format to add.

    Returns
    -------
    Format
        ``fmt`` itself (so a format module may write ``FMT = register(Format(...))``).

    Raises
    ------
    ValueError
        A name already registered; a container other than ``"hdf5"``, ``"file"`` or
        ``"any"``; ``export_from`` without ``export`` or the reverse.
    """
    if fmt.name in FORMATS:
        raise ValueError(f"format {fmt.name!r} is registered already")
    if fmt.container not in ("hdf5", "file", "any"):
        raise ValueError(f"container must be 'hdf5', 'file' or 'any', got {fmt.container!r}")
    if (fmt.export_from is None) != (fmt.export is None):
        raise ValueError(f"format {fmt.name!r}: export_from and export go together")
    put_in_order(FORMATS, fmt.name, fmt, lambda f: f.rank)
    return fmt


def unregister(name: str) -> None:
    """Remove the format ``name`` (a test's toy format); no error when it is not there.

    Parameters
    ----------
    name : str
        The registered name (:attr:`Format.name`).
    """
    FORMATS.pop(name, None)


def names(*, input: bool | None = None, upload: bool | None = None) -> tuple[str, ...]:
    """The registered formats' names in list order (:attr:`Format.rank`), those with the given flags.

    Parameters
    ----------
    input : bool, optional
        Only formats whose :attr:`Format.input` is this (a reconstruction input or not);
        None (default): either.
    upload : bool, optional
        Only formats whose :attr:`Format.upload` is this (accepted by ``POST /api/datasets``
        or not); None (default): either.

    Returns
    -------
    tuple of str
        The format names.
    """
    return tuple(f.name for f in FORMATS.values()
                 if (input is None or f.input == input) and (upload is None or f.upload == upload))


def _get(name: str, choices: tuple[str, ...] | None = None) -> Format:
    allowed = names() if choices is None else choices
    if name not in allowed:
        raise ValueError(f"format must be one of {', '.join(allowed)}, got {name!r}")
    return FORMATS[name]


@contextmanager
def open_source(path: str | os.PathLike, container: str | None = None, *,
                max_bytes: int = MAX_BYTES, name: str | None = None) -> Iterator[Source]:
    """Open ``path`` once for detection and loading (module docstring); a context manager.

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    container : {"hdf5", "file", "any"} or None, optional
        The container a chosen format needs: ``"hdf5"``: a file without the HDF5 signature
        is refused, naming the format ``name``; ``"file"``: not opened as HDF5; None
        (default) or ``"any"``: from the signature (at 0, or at 512 behind a user block:
        :data:`HDF5_OFFSETS`).
    max_bytes : int, optional
        The bound on any one HDF5 dataset's declared bytes (``check_hdf5_file``); default
        :data:`MAX_BYTES`.
    name : str, optional
        The chosen format's name, for the message when ``container="hdf5"`` refuses a file.

    Returns
    -------
    contextlib.AbstractContextManager of Source
        Entered (``with open_source(path) as src``), the open file: ``h5`` set (checked) for
        an HDF5 file, else ``fh``; closed when the ``with`` block ends.

    Raises
    ------
    FileNotFoundError
        No file ``path``.
    ValueError
        Not the container asked for (with a hint for a MATLAB MAT-file); an HDF5 file that
        is unreadable (truncated or corrupt) or refused by ``check_hdf5_file``.
    """
    from fpscan.driver.scanfile import open_readonly
    from fpscan.service.formats.untrusted import check_hdf5_file

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}")
    with open(path, "rb") as fh:
        head = fh.read(HEAD_BYTES)
        fh.seek(0)
        offset = _hdf5_offset(head)
        if container == "hdf5" and offset is None:
            raise ValueError(f"{'a ' + name if name else 'the'} file must be HDF5 (no HDF5 signature at the start)"
                             + _mat_hint(head))
        if offset is None or container == "file":
            yield Source(path=path, head=head, fh=fh)
            return
    try:
        f = open_readonly(path) if offset == 0 else _open_behind_user_block(path)
    except Exception:  # ValueError from the superblock checks; damaged files can reach other paths
        raise ValueError("not a readable HDF5 file (truncated or corrupt)") from None
    with f:
        check_hdf5_file(f, max_bytes=max_bytes)
        yield Source(path=path, head=head, h5=f)


def _open_behind_user_block(path: Path) -> Any:
    """An HDF5 file whose superblock sits behind a 512-byte user block (a MATLAB v7.3
    MAT-file), opened read-only without SWMR: ``fpscan.driver.scanfile.open_readonly`` checks a
    superblock at 0 only, and these files come from MATLAB, never from a writer fpscan
    reads while it writes (a file flagged as open for writing is refused by HDF5 itself,
    which is what a plain open does: no SWMR retries). Raises OSError."""
    import h5py

    return h5py.File(path, "r", locking=False)


def _mat_hint(head: bytes) -> str:
    """For a MATLAB MAT-file asked to be read as plain HDF5: which format reads it."""
    if head.startswith(b"MATLAB"):
        return "; this is a MATLAB MAT-file: read it with format kwave-mat"
    return ""


def sniff(source: Source) -> Format | None:
    """The first registered format (by ``order``) of ``source``'s container (or of
    container ``"any"``) whose ``sniff`` accepts it.

    Parameters
    ----------
    source : Source
        The file, opened by :func:`open_source`.

    Returns
    -------
    Format or None
        The format; None when none accepts it.
    """
    container = "hdf5" if source.h5 is not None else "file"
    for fmt in sorted(FORMATS.values(), key=lambda f: f.order):
        if fmt.sniff is not None and fmt.container in (container, "any") and fmt.sniff(source):
            return fmt
    return None


def detect(path: str | os.PathLike, *, max_bytes: int = MAX_BYTES, bounded: bool = True) -> str:
    """The name of ``path``'s format, from its content (the file opened once and checked:
    :func:`open_source`).

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    max_bytes : int, optional
        The bound on any one HDF5 dataset's declared bytes; default :data:`MAX_BYTES`.
    bounded : bool, optional
        True (default): a file a writer has open is read in a bounded child process, as
        :func:`load`; False: in this process whatever the file.

    Returns
    -------
    str
        The registered format's name.

    Raises
    ------
    ValueError
        No registered format fits, or the file is refused (:func:`open_source`).
    FileNotFoundError
        No file ``path``.
    """
    if bounded:
        from fpscan.service.formats.untrusted import read_bounded

        return read_bounded(detect, path, max_bytes=max_bytes, bounded=False)
    with open_source(path, max_bytes=max_bytes) as src:
        fmt = sniff(src)
        if fmt is None:
            raise ValueError(_unknown(src, names(input=True)))
    return fmt.name


def describe(path: str | os.PathLike, *, unless: tuple[str, ...] = (), max_bytes: int = MAX_BYTES) -> str | None:
    """What the file ``path`` is, as a noun for a message.

    The one format sniffer of every "this is a scan file, not a plan" message; never raises.

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    unless : tuple of str, optional
        Format names for which None is returned (a caller that wanted that format gives
        its own reason); default none.
    max_bytes : int, optional
        The bound on any one HDF5 dataset's declared bytes; default :data:`MAX_BYTES`.

    Returns
    -------
    str or None
        :attr:`Format.what` of the format :func:`detect` finds (``"a scan file"``, ``"a
        reconstruction result"``, ``"a NumPy .npy array"``); ``"an HDF5 file"`` for an HDF5
        file no format fits (or one refused as hostile or unreadable); None for a file of no
        known format, a missing or unreadable file, or one detected as a format in ``unless``.
    """
    try:
        name = detect(path, max_bytes=max_bytes)
    except (ValueError, OSError):
        from fpscan.service.formats.untrusted import is_hdf5

        try:
            return "an HDF5 file" if is_hdf5(path) else None
        except OSError:
            return None
    return None if name in unless else FORMATS[name].what


def _unknown(source: Source, choices: tuple[str, ...]) -> str:
    """The reason a file fits none of ``choices``."""
    if source.h5 is None:
        others = [FORMATS[n].what for n in choices if n in FORMATS and FORMATS[n].container in ("file", "any")]
        return f"file is neither HDF5 nor {' nor '.join(others) or 'another known format'}"
    return f"the HDF5 file is in none of the known formats ({', '.join(choices)})"


#: what a format's reader raises on a file whose structure its own checks did not foresee (a
#: missing key, a string where a number belongs, an index past an array, a number past float's
#: range): :func:`load` turns these into a ``ValueError`` naming the format, as a file the reader
#: refused with its own reason. A ``MemoryError`` stays one: the bounded import's child names the
#: memory limit it met (``fpscan.service.formats.untrusted.run_bounded``)
UNREADABLE = (KeyError, IndexError, TypeError, AttributeError, ArithmeticError)


def load(path: str | os.PathLike, kind: str | None = None, *, max_bytes: int = MAX_BYTES,
         choices: tuple[str, ...] | None = None, bounded: bool = True, **options: Any) -> tuple[str, Any]:
    """Open ``path`` once, check it, and load it as the format ``kind``.

    A file HDF5 would open as an SWMR reader (a writer has it open: HDF5 can block on its
    damaged metadata for ever) is read in a spawned child process with a time limit
    (``fpscan.service.formats.untrusted.read_bounded``; there fpscan's own formats and the plugins of
    the ``fpscan.formats`` entry points are registered, and the content must be picklable) unless
    ``bounded`` is False.

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    kind : str, optional
        The format's name; None (default): detected from the content (:func:`sniff`; a
        format with :attr:`Format.refuse` set is refused with its reason).
    max_bytes : int, optional
        The bound on any one array's declared bytes, passed to ``check_hdf5_file`` and to
        the format's ``load``; default :data:`MAX_BYTES`.
    choices : tuple of str, optional
        The format names allowed; None (default): every registered one.
    bounded : bool, optional
        True (default): as above; False: in this process whatever the file (the service's
        own scan file while it is written: the live preview).
    **options
        Passed to the format's ``load`` (each takes what it knows). ``wavelength_index`` > 0
        is refused for a format without several wavelengths; ``all_wavelengths=True`` gives
        a list, one content per wavelength (a format with ``wavelengths`` reads them all
        from its one open; any other gives a list of one).

    Returns
    -------
    name : str
        The format's name (``kind``, or the one detected).
    content : object
        What the format's ``load`` returns (a ``GridDataset`` / ``PointDataset`` for an
        input format), or a list of them with ``all_wavelengths=True``.

    Raises
    ------
    ValueError
        A name not in ``choices``; a file no format fits, that is refused, or of a detected
        format not in ``choices``; a format without a reader; a wavelength index out of
        range; what the format's ``load`` raises (a ``KeyError``, ``IndexError``, ``TypeError``,
        ``AttributeError`` or ``ArithmeticError`` of its reader too, as a ``ValueError`` naming
        the format: `UNREADABLE`); a bounded read that did not end in time.
    FileNotFoundError
        No file ``path``.
    """
    if bounded:
        from fpscan.service.formats.untrusted import read_bounded

        return read_bounded(load, path, kind, max_bytes=max_bytes, choices=choices, bounded=False, **options)
    fmt = _get(kind, choices) if kind is not None else None
    with open_source(path, fmt.container if fmt is not None else None, max_bytes=max_bytes,
                     name=kind) as src:
        if fmt is None:
            fmt = sniff(src)
            if fmt is None:
                raise ValueError(_unknown(src, names(input=True) if choices is None else choices))
            if fmt.refuse:
                raise ValueError(fmt.refuse)
            if choices is not None and fmt.name not in choices:
                raise ValueError(f"this is {fmt.what}, not one of {', '.join(choices)}")
        if fmt.load is None:
            raise ValueError(f"{fmt.name} is a format fpscan writes only (no reader)")
        index = options.get("wavelength_index") or 0
        if index and not fmt.wavelengths:
            raise ValueError(f"wavelength index {index} is out of range: a {fmt.name} file holds one "
                             "wavelength's data")
        try:
            if options.get("all_wavelengths") and not fmt.wavelengths:  # one wavelength: a list of one
                return fmt.name, [fmt.load(src, max_bytes=max_bytes,
                                           **{k: v for k, v in options.items() if k != "all_wavelengths"})]
            return fmt.name, fmt.load(src, max_bytes=max_bytes, **options)
        except UNREADABLE as exc:  # a reader met a structure its checks did not foresee
            raise ValueError(f"this file does not read as {fmt.what} ({type(exc).__name__}: {exc})") from exc


def export_formats(source: str | None = None) -> tuple[str, ...]:
    """The names of the export formats (:attr:`Format.export_from` set), in list order.

    Parameters
    ----------
    source : str, optional
        Only those that export files of this format (``"result"``: a reconstruction's
        ``volume.h5``; ``"fpscan"``: a scan file); None: every export format.

    Returns
    -------
    tuple of str
    """
    return tuple(f.name for f in FORMATS.values()
                 if f.export_from is not None and (source is None or f.export_from == source))


def export_file(src: str | os.PathLike, out: str | os.PathLike, format: str) -> Path:
    """Write the export ``format`` of the file ``src``: the one export dispatch of ``fpscan
    export``, ``GET /api/jobs/{id}/export/{format}`` and the ``fpscan`` package.

    Parameters
    ----------
    src : str or os.PathLike
        A file of the format's :attr:`Format.export_from` (a result ``volume.h5`` or a scan
        file), detected from its content (:func:`detect`: opened once and checked).
    out : str or os.PathLike
        Where to write (a folder for a :attr:`Format.folder` export; an existing export there is
        replaced).
    format : str
        One of :func:`export_formats`.

    Returns
    -------
    pathlib.Path
        ``out``.

    Raises
    ------
    ValueError
        An unknown export format; ``src`` of another format (naming what it is and what the
        format exports from); what the exporter refuses.
    FileNotFoundError
        No file ``src``.
    """
    allowed = export_formats()
    if format not in allowed:
        raise ValueError(f"export format must be one of {', '.join(allowed)}, got {format!r}")
    fmt = FORMATS[format]
    src = Path(src)
    found = detect(src)
    if found != fmt.export_from:
        want = FORMATS[fmt.export_from].what if fmt.export_from in FORMATS else fmt.export_from
        raise ValueError(f"{fmt.name} exports {want}; {src.name} is {FORMATS[found].what} "
                         f"(its exports: {', '.join(export_formats(found)) or 'none'})")
    assert fmt.export is not None  # register() keeps export_from and export together
    return fmt.export(src, Path(out))
