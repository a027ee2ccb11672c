"""fpscan clients: the Python HTTP client, the `fpscan` command line and the web page."""

__all__: list[str] = []  # the package's API is its modules
