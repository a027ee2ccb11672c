import sys

from fpscan.clients.cli import main

sys.exit(main())
