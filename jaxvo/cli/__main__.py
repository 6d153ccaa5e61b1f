"""``python -m jaxvo.cli.main``: the ``jaxvo`` command."""

import sys

from jaxvo.cli.main import main

sys.exit(main())
