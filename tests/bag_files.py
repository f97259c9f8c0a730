"""A small bag written with the real ``rosbags`` writer, for the fuzz and corpus tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np

RNG = np.random.default_rng(7)
N = 40
#: x, y, z, intensity of the bag's one cloud
PTS = np.column_stack([RNG.uniform(-20, 20, (N, 3)), RNG.integers(0, 255, N)]).astype(np.float32)
W, H = 48, 32
EV = dict(x=RNG.integers(0, W, 50), y=RNG.integers(0, H, 50), t=np.sort(RNG.integers(0, 400_000, 50)),
          p=RNG.integers(0, 2, 50))


def write_bag(path: Path, ros2: bool, storage: str = "sqlite3", points: np.ndarray = PTS) -> None:
    """Two dvs_msgs/EventArray messages and one PointCloud2, with the real ``rosbags`` writer."""
    from l2e_studio.io.bags import make_typestore

    store = make_typestore(ros2)
    T = store.types
    Time, Header = T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"]
    head = Header(stamp=Time(sec=1, nanosec=0), frame_id="f") if ros2 else \
        Header(seq=0, stamp=Time(sec=1, nanosec=0), frame_id="f")
    Event, EventArray = T["dvs_msgs/msg/Event"], T["dvs_msgs/msg/EventArray"]
    msgs = []
    for m in range(2):
        sl = slice(m * 25, m * 25 + 25)
        evs = [Event(x=int(x), y=int(y), ts=Time(sec=1, nanosec=int(t) * 1000), polarity=bool(p))
               for x, y, t, p in zip(EV["x"][sl], EV["y"][sl], EV["t"][sl], EV["p"][sl])]
        msgs.append(EventArray(header=head, height=H, width=W, events=evs))
    PointField, PointCloud2 = T["sensor_msgs/msg/PointField"], T["sensor_msgs/msg/PointCloud2"]
    fields = [PointField(name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate(("x", "y", "z", "intensity"))]
    cloud = PointCloud2(header=head, height=1, width=len(points), fields=fields, is_bigendian=False, point_step=16,
                        row_step=16 * len(points), data=np.frombuffer(points.astype("<f4").tobytes(), np.uint8), is_dense=True)
    if ros2:
        from rosbags.rosbag2 import StoragePlugin, Writer

        writer = Writer(path, version=9, storage_plugin=StoragePlugin[storage.upper()])
        serialize = store.serialize_cdr
    else:
        from rosbags.rosbag1 import Writer

        writer, serialize = Writer(path), store.serialize_ros1
    with writer:
        ev = writer.add_connection("/events", "dvs_msgs/msg/EventArray", typestore=store)
        pc = writer.add_connection("/points", "sensor_msgs/msg/PointCloud2", typestore=store)
        for i, msg in enumerate(msgs):
            writer.write(ev, 1_000_000_000 + i * 1000, serialize(msg, ev.msgtype))
        writer.write(pc, 1_000_000_500, serialize(cloud, pc.msgtype))
