"""``python -m controller``: the same as ``aider-exo controller``."""

import sys

from tools.cli import main

sys.exit(main(["controller", *sys.argv[1:]]))
