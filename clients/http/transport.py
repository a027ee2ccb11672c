"""What both clients share on the wire: the connection settings, the error of a 4xx/5xx
answer, resumable downloads and the OME-Zarr zip's unpacking.

:class:`fpscan.clients.http.client.Client` and :class:`fpscan.clients.http.async_client.AsyncClient` send with
``httpx`` (blocking or ``asyncio``) what :mod:`fpscan.clients.http.core`'s flows ask for; everything
here is the same for both. Downloads go to
``<dest>.part`` and are renamed into place when complete; one cut off by a network failure
resumes where it stopped on the next call (HTTP ``Range`` with ``If-Range``, RFC 9110
§14.2 / §13.1.5, so a changed file is fetched whole).
"""
from __future__ import annotations

import os
import shutil
import uuid
import zipfile
from pathlib import Path
from typing import IO, Any

import httpx

from fpscan.clients.http.errors import ServerUnavailable, error_for_status

__all__ = ["Connection", "raise_for", "Resume", "RangeMismatch", "MAX_ZIP_RATIO", "unzip_folder"]


class Connection:
    """The settings of a client: server URL, bearer token, timeout.

    Parameters
    ----------
    base_url : str, optional
        ``http://`` or ``https://`` URL of the server; default ``$FPSCAN_SERVER`` or
        ``http://127.0.0.1:8000``.
    token : str, optional
        Bearer token; default ``$FPSCAN_TOKEN`` (``""``: send none).
    timeout : float, optional
        Seconds per request (default 30).

    Attributes
    ----------
    base_url : str
        Without a trailing slash.
    token : str or None
    timeout : float
        s.

    Raises
    ------
    ValueError
        A URL that is not http(s).

    Examples
    --------
    >>> from fpscan.clients.http.transport import Connection
    >>> c = Connection("http://127.0.0.1:8000/", token="s3cret")
    >>> c.base_url, c.headers()["Authorization"]
    ('http://127.0.0.1:8000', 'Bearer s3cret')
    """

    def __init__(self, base_url: str | None = None, *, token: str | None = None,
                 timeout: float = 30.0) -> None:
        base_url = base_url or os.environ.get("FPSCAN_SERVER") or "http://127.0.0.1:8000"
        if not base_url.startswith(("http://", "https://")):
            raise ValueError(f"server URL must start with http:// or https://, not {base_url!r}")
        self.base_url = base_url.rstrip("/")
        self.token = token if token is not None else os.environ.get("FPSCAN_TOKEN") or None
        self.timeout = timeout

    def headers(self) -> dict[str, str]:
        """The headers of every request: ``Accept`` and, with a token, ``Authorization``.

        Returns
        -------
        dict
        """
        h = {"Accept": "application/json"}
        if self.token:
            h["Authorization"] = f"Bearer {self.token}"
        return h

    def unavailable(self, exc: Exception) -> ServerUnavailable:
        """The :class:`ServerUnavailable` of a transport failure ``exc``.

        Parameters
        ----------
        exc : Exception

        Returns
        -------
        ServerUnavailable
        """
        return ServerUnavailable(self.base_url, str(exc) or type(exc).__name__)


def _detail(response: httpx.Response) -> Any:
    try:
        body = response.json()
    except ValueError:
        text = response.text.strip()
        return text[:500] or response.reason_phrase
    if isinstance(body, dict) and "detail" in body:
        return body["detail"]
    return body


def raise_for(response: httpx.Response) -> None:
    """Raise the :class:`~fpscan.clients.http.errors.ApiError` of a 4xx/5xx answer (its subclass by
    status), carrying the server's ``detail`` verbatim; nothing for a 1xx-3xx.

    Parameters
    ----------
    response : httpx.Response
        Read (its body available).

    Raises
    ------
    ApiError
        ``AuthError`` (401/403), ``NotFound`` (404), ``Conflict`` (409) or ``ApiError``.

    Examples
    --------
    >>> import httpx
    >>> from fpscan.clients.http.transport import raise_for
    >>> r = httpx.Response(404, json={"detail": "no job j1"}, request=httpx.Request("GET", "http://h/api/jobs/j1"))
    >>> raise_for(r)
    Traceback (most recent call last):
    ...
    fpscan.clients.http.errors.NotFound: HTTP 404: no job j1
    """
    if response.status_code >= 400:
        raise error_for_status(response.status_code, _detail(response), method=response.request.method,
                               url=str(response.request.url))


class RangeMismatch(ValueError):
    """A 206 whose ``Content-Range`` does not continue the partial file (another start, or no
    range): its bytes must not be appended (RFC 9110 §14.4); the download starts over.

    A ``ValueError`` raised by :meth:`Resume.open`.

    Attributes
    ----------
    args : tuple
        The message: the range the server stated and the bytes held.

    Examples
    --------
    >>> from fpscan.clients.http.transport import RangeMismatch
    >>> issubclass(RangeMismatch, ValueError)
    True
    """


class Resume:
    """Resumable download state of ``dest``: ``dest.part`` (bytes so far) and
    ``dest.part.etag`` (the validator they came with). A later download of the same
    file asks for the rest only (``Range`` + ``If-Range``, RFC 9110 §14.2/§13.1.5); the
    server answers 206 with the remainder if the file is unchanged, else 200 with all of it.

    Parameters
    ----------
    dest : pathlib.Path
        The file the download ends in.

    Attributes
    ----------
    dest, part, meta : pathlib.Path
        The file, its partial file and the partial file's validator.

    Examples
    --------
    >>> from pathlib import Path
    >>> from fpscan.clients.http.transport import Resume
    >>> r = Resume(Path("/tmp/none/scan.h5"))
    >>> r.part.name, r.headers()  # nothing held yet: ask for everything
    ('scan.h5.part', {})
    """

    def __init__(self, dest: Path) -> None:
        self.dest = dest
        self.part = dest.with_name(dest.name + ".part")
        self.meta = self.part.with_name(self.part.name + ".etag")

    def headers(self) -> dict[str, str]:
        """``Range`` and ``If-Range`` for the bytes not yet held (none when nothing is).

        Returns
        -------
        dict
        """
        if self.part.exists() and self.meta.exists() and self.part.stat().st_size > 0:
            return {"Range": f"bytes={self.part.stat().st_size}-", "If-Range": self.meta.read_text()}
        return {}

    def open(self, response: httpx.Response) -> IO[bytes]:
        """The file to write the body into: appended on 206, rewritten otherwise.

        Parameters
        ----------
        response : httpx.Response
            The answer whose body follows (its validator, ``ETag`` or ``Last-Modified``, is kept).

        Returns
        -------
        file
            Opened for binary writing.
        """
        if response.status_code == 206:
            held = self.part.stat().st_size if self.part.exists() else 0
            stated = response.headers.get("content-range", "")
            unit, _, span = stated.partition(" ")
            if unit.strip().lower() != "bytes" or span.split("-", 1)[0].strip() != str(held):
                raise RangeMismatch(f"the server's partial answer ({stated or 'no Content-Range'}) does not "
                                    f"continue the {held} bytes held")
        validator = response.headers.get("etag") or response.headers.get("last-modified")
        if validator:
            self.meta.write_text(validator)
        else:
            self.meta.unlink(missing_ok=True)
        return open(self.part, "ab" if response.status_code == 206 else "wb")

    def done(self) -> Path:
        """The complete file moved into place.

        Returns
        -------
        pathlib.Path
            ``dest``.
        """
        os.replace(self.part, self.dest)
        self.meta.unlink(missing_ok=True)
        return self.dest

    def discard(self) -> None:
        """Forget the partial file (the next download starts over)."""
        self.part.unlink(missing_ok=True)
        self.meta.unlink(missing_ok=True)


#: the most a zip may unpack to per byte of its own: an OME-Zarr export's chunks are compressed
#: already (about 1:1 in the zip, its JSON some 10:1); a zip of zeros packs 1000:1 and more
MAX_ZIP_RATIO = 100


def unzip_folder(zipped: Path, dest: Path) -> Path:
    """Unpack a zip holding one top folder (an OME-Zarr export) into the folder ``dest``
    (the top folder's name dropped), via a temporary sibling renamed into place.

    Parameters
    ----------
    zipped : pathlib.Path
        The zip file.
    dest : pathlib.Path
        The folder to make (an existing one there is replaced).

    Returns
    -------
    pathlib.Path
        ``dest``.

    Raises
    ------
    ValueError
        A zip that is not one folder, or names a path outside it; one that would unpack to more
        than :data:`MAX_ZIP_RATIO` times its size (a zip bomb), or to more than the free space
        of ``dest``'s disk (the sizes its directory declares, which bound what ``zipfile``
        unpacks).

    Examples
    --------
    >>> import tempfile, zipfile
    >>> from pathlib import Path
    >>> from fpscan.clients.http.transport import unzip_folder
    >>> tmp = Path(tempfile.mkdtemp())
    >>> with zipfile.ZipFile(tmp / "v.zip", "w") as z:
    ...     z.writestr("volume.ome.zarr/zarr.json", "{}")
    >>> sorted(p.name for p in unzip_folder(tmp / "v.zip", tmp / "out.ome.zarr").iterdir())
    ['zarr.json']
    """
    tmp = dest.with_name(f".{dest.name}.{uuid.uuid4().hex[:12]}.tmp")
    try:
        with zipfile.ZipFile(zipped) as z:
            names = [n for n in z.namelist() if not n.endswith("/")]
            tops = {n.split("/", 1)[0] for n in names}
            if len(tops) != 1 or any("/" not in n for n in names):
                raise ValueError(f"{zipped.name}: expected one folder in the zip, found {sorted(tops)[:5]}")
            total, packed = sum(i.file_size for i in z.infolist()), max(1, zipped.stat().st_size)
            if total > MAX_ZIP_RATIO * packed:
                raise ValueError(f"{zipped.name}: {packed} bytes that unpack to {total} ({total // packed}:1, over "
                                 f"the {MAX_ZIP_RATIO}:1 an export reaches): refused, not unpacked")
            free = shutil.disk_usage(dest.parent).free
            if total > free:
                raise ValueError(f"{zipped.name} unpacks to {total} bytes; {dest.parent} has {free} free")
            for n in names:
                rel = Path(n.split("/", 1)[1])
                if rel.is_absolute() or ".." in rel.parts:
                    raise ValueError(f"{zipped.name}: unsafe path {n!r} in the zip")
                target = tmp / rel
                target.parent.mkdir(parents=True, exist_ok=True)
                with z.open(n) as src, open(target, "wb") as out:
                    shutil.copyfileobj(src, out)
        if dest.exists():
            shutil.rmtree(dest) if dest.is_dir() else dest.unlink()
        tmp.rename(dest)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return dest
