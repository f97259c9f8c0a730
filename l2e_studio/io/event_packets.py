"""``event_camera_msgs/msg/EventPacket``: what the current ROS 1 / ROS 2 event camera drivers
(metavision_driver for Prophesee sensors, libcaer_driver for iniVation) publish.

The message carries the camera's own encoding in ``events`` (uint8[]), named by ``encoding``:

* ``evt3`` -- raw Prophesee EVT 3.0 words as the SDK hands them over; the packets of a topic are
  consecutive pieces of one stream (a packet may end between a y word and its x words), so one
  stateful :class:`~l2e_studio.io.event_codecs.Evt3Decoder` reads the whole topic, and times are
  the sensor's microseconds (``time_base`` is unused by this encoding);
* ``mono`` and ``libcaer`` -- 64 bits an event, times after the message's ``time_base`` (ns);
* ``trigger`` packets hold external trigger edges, no pixel events, and ``libcaer_cmp``
  (libcaer_driver's compressed format) is not read: both are refused with that reason.

Times come out in microseconds, like every other event source.
"""

from __future__ import annotations

import numpy as np

from . import event_codecs as codecs

PACKET_TYPE = "event_camera_msgs/msg/EventPacket"

#: The message definition (event_camera_msgs' EventPacket.msg; ROS 1 spells the header ``Header``).
PACKET_MSG = """std_msgs/Header header
uint32 height
uint32 width
uint64 seq
uint64 time_base
string encoding
bool is_bigendian
uint8[] events
"""

ENCODINGS = ("evt3", "mono", "libcaer")
_REFUSED = {
    "trigger": "it carries external trigger edges, not pixel events; choose the camera's event topic",
    "libcaer_cmp": "libcaer_driver's compressed encoding is not read; record with encoding libcaer",
}


def packet_types() -> dict:
    """EventPacket's definition, as rosbags' typestores register it."""
    from rosbags.typesys import get_types_from_msg

    return get_types_from_msg(PACKET_MSG, PACKET_TYPE)


class PacketError(ValueError):
    """An EventPacket topic that cannot be read (the message says why)."""


class PacketStream:
    """The decoder of one EventPacket topic: call :meth:`decode` with its messages in order."""

    def __init__(self, topic: str) -> None:
        self.topic = topic
        self.encoding: str | None = None
        self._evt3: codecs.Evt3Decoder | None = None

    def decode(self, msg) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(x, y, t_us, p) of one message; :class:`PacketError` for what cannot be read, with the reason."""
        encoding = str(msg.encoding)
        if self.encoding is None:
            self._check(encoding, bool(msg.is_bigendian))
            self.encoding = encoding
        elif encoding != self.encoding:
            raise PacketError(f"topic {self.topic} changes encoding from {self.encoding!r} to {encoding!r}")
        data = np.asarray(msg.events, dtype=np.uint8)
        if encoding == "evt3":
            if self._evt3 is None:
                self._evt3 = codecs.Evt3Decoder()
            return codecs.concat(list(self._evt3.decode_bytes(data)))
        if data.size % 8:
            raise PacketError(f"a {encoding} packet on {self.topic} holds {data.size} bytes, not a multiple of 8")
        if encoding == "mono":
            return codecs.decode_mono(data, int(msg.time_base))
        return codecs.decode_libcaer(data, int(msg.time_base))

    def _check(self, encoding: str, big_endian: bool) -> None:
        if encoding in _REFUSED:
            raise PacketError(f"topic {self.topic} has EventPackets in encoding {encoding!r}: {_REFUSED[encoding]}")
        if encoding not in ENCODINGS:
            raise PacketError(f"topic {self.topic} has EventPackets in encoding {encoding!r}; "
                             f"read are {', '.join(ENCODINGS)}")
        if big_endian:
            raise PacketError(f"topic {self.topic} has big-endian EventPackets; only little-endian ones are read")
