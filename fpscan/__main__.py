"""``python -m fpscan``: the ``fpscan`` command line (:func:`fpscan.clients.cli.main`)."""
import sys

from fpscan.clients.cli import main

sys.exit(main())
