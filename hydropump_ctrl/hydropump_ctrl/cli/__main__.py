"""``python -m hydropump_ctrl.cli``: the ``hydropump`` command."""

import sys

from . import main

sys.exit(main())
