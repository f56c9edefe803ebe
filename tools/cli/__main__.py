"""``python -m tools.cli``: the same as the ``aider-exo`` command."""

import sys

from tools.cli import main

sys.exit(main())
