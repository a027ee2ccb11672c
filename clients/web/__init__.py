"""The web page (index.html, app.js, style.css) that ``fpscan serve`` serves at ``/``: static
files, no Python API; its README says how the page is built and tested."""

__all__: list[str] = []  # the package's API is its files
