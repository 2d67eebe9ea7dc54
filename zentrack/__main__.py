"""``python -m zentrack``."""
import sys

from zentrack.cli import main

sys.exit(main())
