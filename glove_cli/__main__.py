"""``python -m glove_cli`` runs the ``glove`` command."""

import sys

from glove_cli.main import main

sys.exit(main())
