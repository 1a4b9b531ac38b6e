"""The view's command-line options (mmsnap_graph.app.view.arguments)."""

from __future__ import annotations

import argparse

import pytest

from mmsnap_graph.app.view.arguments import add_view_options, view_sink
from mmsnap_graph.errors import ValidationError


def _args(*argv):
    p = argparse.ArgumentParser()
    add_view_options(p)
    p.add_argument("--overwrite", action="store_true")
    return p.parse_args(list(argv))


def test_no_view_option_no_sink_and_the_defaults():
    args = _args()
    assert view_sink(args, ["S1"], [[0, 0, 0]]) is None
    assert (args.view, args.view_log, args.view_port, args.view_history) == (False, None, 8765,
                                                                            10.0)


def test_a_bad_port_or_history_is_a_usage_error(tmp_path):
    pytest.importorskip("foxglove")
    with pytest.raises(ValidationError, match="port=70000"):
        view_sink(_args("--view", "--view-port", "70000"), ["S1"], [[0, 0, 0]])
    with pytest.raises(ValidationError, match="history_s"):
        view_sink(_args("--view-log", str(tmp_path / "v.mcap"), "--view-history", "-1"),
                  ["S1"], [[0, 0, 0]])


def test_view_serves_on_the_port_and_says_where(capsys):
    pytest.importorskip("foxglove")
    view = view_sink(_args("--view", "--view-port", "0"), ["S1"], [[0, 0, 0]])
    try:
        assert view.url.startswith("ws://127.0.0.1:") and not view.url.endswith(":0")
        assert f"connect to {view.url}" in capsys.readouterr().err
    finally:
        view.close()
