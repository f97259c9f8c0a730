"""Bags without ROS: ROS 1 and ROS 2 bags written with rosbags' writers, extracted to scene folders."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from l2e_studio.cli import main
from l2e_studio.errors import InputError
from l2e_studio.io.bags import ExtractSettings, extract_bag, list_topics, make_typestore
from l2e_studio.io.cameras import load_rig
from l2e_studio.io.lidar import load_lidar
from l2e_studio.io.maps import load_map

W, H = 48, 32
RNG = np.random.default_rng(11)
POINTS = RNG.uniform(-5, 5, size=(300, 3)).astype(np.float32)
INTEN = RNG.integers(1, 255, size=300).astype(np.float32)


def _msgs(store, ros2: bool, pkg: str, n_msgs: int = 20, per_msg: int = 100):
    T = store.types
    Time = T["builtin_interfaces/msg/Time"]
    Header = T["std_msgs/msg/Header"]

    def header(sec: int, nsec: int):
        stamp = Time(sec=sec, nanosec=nsec)
        return Header(stamp=stamp, frame_id="cam") if ros2 else Header(seq=0, stamp=stamp, frame_id="cam")

    Event, EventArray = T[f"{pkg}/msg/Event"], T[f"{pkg}/msg/EventArray"]
    events_all = []
    msgs = []
    for m in range(n_msgs):  # 20 messages, 0.5 s apart: 10 s of events
        xs = RNG.integers(0, W, per_msg)
        ys = RNG.integers(0, H, per_msg)
        t_us = 1_000_000 + m * 500_000 + np.sort(RNG.integers(0, 500_000, per_msg))
        evs = [Event(x=int(x), y=int(y), ts=Time(sec=int(t // 1_000_000), nanosec=int(t % 1_000_000) * 1000),
                     polarity=bool(i % 2)) for i, (x, y, t) in enumerate(zip(xs, ys, t_us))]
        events_all.append((xs, ys, t_us))
        msgs.append((int(t_us[0]) * 1000, EventArray(header=header(1, 0), height=H, width=W, events=evs)))
    PointField, PointCloud2 = T["sensor_msgs/msg/PointField"], T["sensor_msgs/msg/PointCloud2"]
    rec = np.zeros(len(POINTS), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("pad", "<f4"),
                                       ("intensity", "<f4"), ("ring", "<u2"), ("pad2", "<u2")])
    rec["x"], rec["y"], rec["z"] = POINTS.T
    rec["intensity"] = INTEN
    fields = [PointField(name=n, offset=o, datatype=d, count=1)
              for n, o, d in (("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("intensity", 16, 7), ("ring", 20, 4))]
    clouds = [(int(1_000_000 + k * 5_000_000) * 1000 + 1,
               PointCloud2(header=header(1, 0), height=1, width=len(POINTS), fields=fields, is_bigendian=False,
                           point_step=24, row_step=24 * len(POINTS), data=np.frombuffer(rec.tobytes(), np.uint8),
                           is_dense=True)) for k in range(2)]
    return msgs, clouds, events_all


def _write(path: Path, ros2: bool, pkg: str = "dvs_msgs", info: bool = True) -> list:
    store = make_typestore(ros2)
    msgs, clouds, events_all = _msgs(store, ros2, pkg)
    if ros2:
        from rosbags.rosbag2 import Writer

        writer = Writer(path, version=9)
        serialize = store.serialize_cdr
    else:
        from rosbags.rosbag1 import Writer

        writer = Writer(path)
        serialize = store.serialize_ros1
    with writer:
        ev = writer.add_connection("/events", f"{pkg}/msg/EventArray", typestore=store)
        pc = writer.add_connection("/points", "sensor_msgs/msg/PointCloud2", typestore=store)
        items = [(t, ev, m) for t, m in msgs] + [(t, pc, m) for t, m in clouds]
        if info:
            ci = writer.add_connection("/camera_info", "sensor_msgs/msg/CameraInfo", typestore=store)
            Info = store.types["sensor_msgs/msg/CameraInfo"]
            Roi = store.types["sensor_msgs/msg/RegionOfInterest"]
            K = np.array([50.0, 0, 24, 0, 50, 16, 0, 0, 1])
            kw = dict(d=np.array([0.1, -0.01, 0.0, 0.0, 0.0]), k=K, r=np.eye(3).ravel(), p=np.zeros(12)) if ros2 else \
                dict(D=np.array([0.1, -0.01, 0.0, 0.0, 0.0]), K=K, R=np.eye(3).ravel(), P=np.zeros(12))
            hdr = msgs[0][1].header
            m = Info(header=hdr, height=H, width=W, distortion_model="plumb_bob", binning_x=0, binning_y=0,
                     roi=Roi(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False), **kw)
            items.append((msgs[0][0], ci, m))
        for t, conn, m in sorted(items, key=lambda it: it[0]):
            writer.write(conn, t, serialize(m, conn.msgtype))
    return events_all


def _expected_map(events_all, begin_us: int, end_us: int) -> np.ndarray:
    grid = np.zeros((H, W))
    for xs, ys, ts in events_all:
        sel = (ts >= begin_us) & (ts < end_us)
        np.add.at(grid, (ys[sel], xs[sel]), 1)
    return np.clip(grid, 0, 127)


@pytest.mark.parametrize("ros2, pkg", [(False, "dvs_msgs"), (False, "prophesee_event_msgs"), (True, "dvs_msgs")])
def test_extract_one_scene_per_bag(tmp_path: Path, ros2: bool, pkg: str) -> None:
    bag = tmp_path / ("rec2" if ros2 else "rec.bag")
    events_all = _write(bag, ros2, pkg)
    topics = {t.name: t for t in list_topics(bag)}
    assert topics["/events"].kind == "events" and topics["/events"].count == 20
    assert topics["/points"].kind == "lidar"
    scenes = extract_bag(bag, tmp_path / "out", ExtractSettings(window_s=3.0))
    assert [s.name for s in scenes] == ["rec2" if ros2 else "rec"]
    image, kind = load_map(scenes[0].map_path)
    first = min(int(ts.min()) for _, _, ts in events_all)
    np.testing.assert_array_equal(image, _expected_map(events_all, first, first + 3_000_000))
    scan = load_lidar(scenes[0].lidar_path)
    np.testing.assert_allclose(scan.points, POINTS)
    np.testing.assert_allclose(scan.intensity, INTEN)
    rig = load_rig(tmp_path / "out" / "camera.yaml")
    assert (rig.width, rig.height) == (W, H) and rig.K[0, 0] == 50 and rig.D[0] == pytest.approx(0.1)


def test_extract_slices_and_cli(tmp_path: Path, capsys) -> None:
    bag = tmp_path / "rec.bag"
    events_all = _write(bag, False, info=False)
    code = main(["extract", str(bag), "--out", str(tmp_path / "out"), "--slice", "5", "--window", "1", "--start", "0.5"])
    assert code == 0
    maps = sorted((tmp_path / "out" / "event").glob("*.png"))
    assert [p.stem for p in maps] == ["rec_0000", "rec_0001"]
    assert len(list((tmp_path / "out" / "lidar").glob("*.pcd"))) == 2
    # Slice 1 starts with the first message at or after bag time + 5 s.
    second = min(int(ts.min()) for _, _, ts in events_all[10:])
    image, _ = load_map(maps[1])
    np.testing.assert_array_equal(image, _expected_map(events_all, second + 500_000, second + 1_500_000))
    assert "2 scene(s) written" in capsys.readouterr().out


def test_topic_choice_and_bad_bags(tmp_path: Path, capsys) -> None:
    bag = tmp_path / "rec.bag"
    _write(bag, False, info=False)
    with pytest.raises(InputError, match="no topic /nope"):
        extract_bag(bag, tmp_path / "o", ExtractSettings(event_topic="/nope"))
    assert main(["extract", str(bag), "--list"]) == 0
    assert "/events" in capsys.readouterr().out
    assert main(["extract", str(bag)]) == 2  # lists, then asks for --out
    bad = tmp_path / "bad.bag"
    bad.write_bytes(b"#ROSBAG V2.0\n" + b"\x00" * 64)
    with pytest.raises(InputError, match="cannot open"):
        list_topics(bad)
    trunc = tmp_path / "trunc.bag"
    trunc.write_bytes(bag.read_bytes()[:3000])
    with pytest.raises(InputError):
        extract_bag(trunc, tmp_path / "o2")
    with pytest.raises(InputError, match="not found"):
        list_topics(tmp_path / "missing.bag")
