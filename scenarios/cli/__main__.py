"""``python -m scenarios.cli``: the ``horizon-nav`` command."""
import sys

from scenarios.cli import main

sys.exit(main())
