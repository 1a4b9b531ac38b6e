"""Settings and strategies shared by the property-based fuzz tests: only the
project's errors (:class:`mmsnap_graph.errors.MmsnapError`) may come out of a
public entry point, and a CLI run on a bad input exits 1 with one line naming
the file. Derandomized (the same examples on every run)."""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

__all__ = ["FUZZ", "CLI_FUZZ", "EDGE", "ANY_VALUE", "one_line_data_error"]

FUZZ = settings(max_examples=40, deadline=None, derandomize=True, database=None,
                report_multiple_bugs=False,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much,
                                       HealthCheck.function_scoped_fixture])
CLI_FUZZ = settings(FUZZ, max_examples=12)

#: Floats a fuzzer should try: ordinary, edge and non-finite values.
EDGE = st.one_of(st.floats(-50, 50, allow_nan=False), st.sampled_from(
    [0.0, -0.0, 1e-300, -1e-300, 1e300, -1e300, np.pi, -np.pi, 4.0, np.nan, np.inf, -np.inf]))
ANY_VALUE = st.one_of(EDGE, st.integers(-10, 10), st.booleans(), st.none(), st.text(max_size=3),
                      st.lists(st.integers(0, 3), max_size=2))


def one_line_data_error(code, err, name):
    """A CLI run that failed on its data: exit 1, one line naming the file."""
    assert code == 1, err
    assert len(err) == 1 and ": error: " in err[0] and name in err[0], err
