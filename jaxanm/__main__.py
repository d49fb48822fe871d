"""``python -m jaxanm``: the ``jaxanm`` command (see :mod:`jaxanm.cli`)."""

import sys

from jaxanm.cli import main

sys.exit(main())
