"""``python -m mmsnap_graph``: the ``mmsnap`` command line (:mod:`mmsnap_graph.app.cli`)."""

import sys

from mmsnap_graph.app.cli import main

if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
