"""``python -m dyndlo_vision`` runs the command-line interface."""

import sys

from dyndlo_vision.cli import main

sys.exit(main())
