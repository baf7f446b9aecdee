"""``python -m armvision.cli``: the same as the ``armvision`` command."""

import sys

from armvision.cli.main import main

sys.exit(main())
