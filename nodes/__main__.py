"""``python -m nodes``: the same as ``aider-exo nodes``."""

import sys

from tools.cli import main

sys.exit(main(["nodes", *sys.argv[1:]]))
