"""A board's CLI port (mmsnap_graph.io.ti.serial.console) against an emulated
board on a real pseudo-terminal (tests/_boards.py)."""

from __future__ import annotations

import pytest
import serial

from mmsnap_graph.errors import ConfigurationError, DeviceError
from mmsnap_graph.io.ti.serial.console import cfg_commands, send_cfg, send_command

from _boards import EmulatedBoard
from _shared import TI_DATA

CFG = (TI_DATA / "iwr1843_oob.cfg").read_text()


def _port(path):
    return serial.Serial(path, 115200, timeout=0.05)


def test_the_cfg_is_sent_between_stop_and_start_and_the_garbled_first_reply_retried():
    with EmulatedBoard([]) as board, _port(board.cli_port) as port:
        replies = send_cfg(port, CFG, board="S1")
        sent = [c for _, c in cfg_commands(CFG)]
        assert board.commands == sent
        assert sent[:2] == ["sensorStop", "flushCfg"] and sent[-1] == "sensorStart"
        assert sent.count("sensorStart") == 1 and "% " not in " ".join(sent)
        assert replies[0].tries == 2 and replies[0].reply == "Ignored: Sensor is already stopped"
        assert all(r.tries == 1 and r.reply == "Done" for r in replies[1:])


def test_each_reply_is_read_as_it_arrives_not_at_the_ports_timeout():
    # A read of 256 bytes waited out the port's timeout on each of the cfg's
    # 29 commands (1.5 s a board at the 0.05 s of a session's CLI port, while
    # the boards configured first streamed into the queue).
    import time
    with EmulatedBoard([], garbled_first=False) as board, \
            serial.Serial(board.cli_port, 115200, timeout=1.0) as port:
        start = time.monotonic()
        replies = send_cfg(port, CFG, board="S1")
        assert len(replies) == 29 and time.monotonic() - start < 10.0


@pytest.mark.parametrize("kw, reply", [(dict(refuse={"cfarCfg"}), "Error -1"),
                                       (dict(unknown={"cfarCfg"}), "'cfarCfg' is not recognized")])
def test_a_refused_line_names_the_board_the_line_and_the_reply(kw, reply):
    with EmulatedBoard([], garbled_first=False, **kw) as board, _port(board.cli_port) as port:
        with pytest.raises(ConfigurationError, match=r"board S7: line 15 'cfarCfg -1 0 2 8 4 3 0 "
                                                     rf"15 1': the board replied .{reply}"):
            send_cfg(port, CFG, board="S7")


def test_a_port_that_does_not_answer():
    with EmulatedBoard([]) as board, _port(board.data_port) as port:
        with pytest.raises(DeviceError, match="board S1: 'sensorStop': no reply .* within 0.3 s"):
            send_command(port, "sensorStop", board="S1", timeout_s=0.3)
