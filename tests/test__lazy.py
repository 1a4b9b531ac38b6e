"""Lazily loaded names (:mod:`mmsnap_graph._lazy`): listed by ``dir()`` before
their first use, loaded on access."""

from __future__ import annotations

import subprocess
import sys


def test_dir_lists_lazy_names_before_they_load():
    code = ("import sys, mmsnap_graph as m; names = dir(m); "
            "print('solve' in names, 'calibrate_recording' in names, "
            "'mmsnap_graph.fusion' in sys.modules, 'gtsam' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["True", "True", "False", "False"]


def test_dir_of_subpackages_lists_their_lazy_names():
    code = ("import mmsnap_graph.radar as r; print('process_cubes' in dir(r), "
            "'process_cubes' in vars(r))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["True", "False"]
