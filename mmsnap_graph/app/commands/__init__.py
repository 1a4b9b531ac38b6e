"""Sub-commands of the ``mmsnap`` command line (see :mod:`mmsnap_graph.app.cli`)."""
