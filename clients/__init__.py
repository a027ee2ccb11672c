"""fpscan clients: the Python HTTP client, the `fpscan` command line and the web page."""
