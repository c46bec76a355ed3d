"""``python -m sweepedit_blender COMMAND ...`` (see cli.py)."""

import sys

from .cli import main

sys.exit(main())
