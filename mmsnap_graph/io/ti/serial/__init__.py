"""TI boards on serial ports (docs/LIVE.md): the data UART's packets and the
incremental parser that files and live ports share.

- :mod:`.packets`: one packet's bytes -> :class:`~.packets.UartPacket`, in each
  layout TI's demos send (out-of-box, 3D People Tracking, legacy People
  Counting), told apart from the bytes;
- :mod:`.stream`: :class:`~.stream.UartStreamParser`, bytes in as they come,
  packets out, with the counts of what it dropped.
"""
