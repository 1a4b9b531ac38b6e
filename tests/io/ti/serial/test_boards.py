"""Which boards on which ports (mmsnap_graph.io.ti.serial.boards): the
--board syntax, the TOML file, ports by USB serial number (pyserial's own
port records)."""

from __future__ import annotations

import pytest
from serial.tools.list_ports_common import ListPortInfo

from mmsnap_graph.errors import ConfigurationError, DeviceError, ValidationError
from mmsnap_graph.io.ti.serial.boards import (BoardSpec, list_boards, parse_board,
                                              read_boards_toml, resolve_port)


def _port(device, serial, vid=0x0451):
    p = ListPortInfo(device, skip_link_detection=True)
    p.serial_number, p.vid, p.description = serial, vid, f"XDS110 {device}"
    return p


PORTS = [_port("scratch/dev/ttyACM1", "R0091049"), _port("scratch/dev/ttyACM0", "R0091049"),
         _port("scratch/dev/ttyACM2", "L1234"), _port("scratch/dev/ttyS0", None, vid=None)]


@pytest.mark.parametrize("text, spec", [
    ("S1=scratch/dev/ttyACM0,scratch/dev/ttyACM1,a.cfg",
     BoardSpec(name="S1", cli_port="scratch/dev/ttyACM0", data_port="scratch/dev/ttyACM1", cfg="a.cfg")),
    ("S2=,COM4", BoardSpec(name="S2", cli_port=None, data_port="COM4")),
    ("S3=usb:R0091049,people.cfg",
     BoardSpec(name="S3", cli_port="usb:R0091049:0", data_port="usb:R0091049:1",
               cfg="people.cfg")),
])
def test_board_syntax(text, spec):
    assert parse_board(text) == spec


@pytest.mark.parametrize("text", ["S1", "=a,b", "S1=a", "S1=a,b,c,d", "S/1=a,b"])
def test_bad_board_syntax(text):
    with pytest.raises(ValidationError):
        parse_board(text)


def test_ports_by_usb_serial_number():
    assert resolve_port("usb:R0091049:0", PORTS) == "scratch/dev/ttyACM0"
    assert resolve_port("usb:R0091049", PORTS, default_index=1) == "scratch/dev/ttyACM1"
    assert resolve_port("scratch/dev/ttyUSB9", PORTS) == "scratch/dev/ttyUSB9"
    with pytest.raises(DeviceError, match=r"no USB serial device has serial number 'X'.*"
                                          r"'L1234', 'R0091049'"):
        resolve_port("usb:X", PORTS)
    with pytest.raises(DeviceError, match="has 1 port"):
        resolve_port("usb:L1234:1", PORTS)
    assert list_boards(PORTS)[0].startswith("scratch/dev/ttyACM0\tusb:R0091049\tXDS110")


def test_boards_from_a_toml_file(tmp_path):
    path = tmp_path / "boards.toml"
    path.write_text('[boards.S1]\ncli = "scratch/dev/ttyACM0"\ndata = "scratch/dev/ttyACM1"\ncfg = "a.cfg"\n'
                    'mount = [1.2, 10]\n[boards.S2]\ndata = "usb:L1234:1"\n')
    s1, s2 = read_boards_toml(path)
    assert s1 == BoardSpec(name="S1", cli_port="scratch/dev/ttyACM0", data_port="scratch/dev/ttyACM1",
                           cfg=str(tmp_path / "a.cfg"), mount=(1.2, 10.0))
    assert (s2.cli_port, s2.data_port) == (None, "usb:L1234:1")
    path.write_text('[boards.S1]\ncli = "x"\n')
    with pytest.raises(ConfigurationError, match="boards.S1 needs 'data'"):
        read_boards_toml(path)
