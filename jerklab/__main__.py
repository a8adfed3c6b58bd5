"""``python -m jerklab``: the ``jerklab`` command (see :mod:`jerklab.cli`)."""

import sys

from jerklab.cli import main

sys.exit(main())
