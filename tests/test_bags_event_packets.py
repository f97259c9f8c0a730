"""event_camera_msgs/EventPacket bags (what metavision_driver and libcaer_driver record), written
with rosbags' own writers (ROS 2 sqlite3 and mcap, ROS 1): ``extract`` must give the same event
map as the raw recording the packets were cut from."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from l2e_studio.cli import main
from l2e_studio.errors import InputError
from l2e_studio.io import event_codecs as codecs
from l2e_studio.io.bags import ExtractSettings, extract_bag, list_topics, make_typestore
from l2e_studio.io.event_prophesee import encode_evt3, read_header
from l2e_studio.io.events import accumulate_events, iter_events
from l2e_studio.io.maps import load_map

W, H = 160, 120
RNG = np.random.default_rng(5)
POINTS = RNG.uniform(-5, 5, size=(200, 3)).astype(np.float32)
INTEN = RNG.integers(1, 255, size=200).astype(np.float32)


@pytest.fixture(scope="module")
def raw_recording(tmp_path_factory) -> Path:
    """An EVT 3.0 file of 5 s: scattered single events and runs along rows (vector words), with a
    24-bit time wrap (times start 1 s before 2^24 us)."""
    n = 60_000
    t = (2**24 - 1_000_000) + np.sort(RNG.integers(0, 5_000_000, n))
    x = RNG.integers(0, W - 12, n)
    y = RNG.integers(0, H, n)
    runs = RNG.random(n) < 0.5  # half the events start a run of 3-10 neighbours at the same time
    reps = np.where(runs, RNG.integers(3, 11, n), 1)
    t, y, p = np.repeat(t, reps), np.repeat(y, reps), np.repeat(RNG.integers(0, 2, n), reps)
    x = np.repeat(x, reps) + np.concatenate([np.arange(r) for r in reps])
    path = tmp_path_factory.mktemp("raw") / "rec.raw"
    path.write_bytes(encode_evt3(x, y, t, p, W, H))
    return path


def _evt3_payloads(raw: Path) -> list[bytes]:
    """The file's words cut into packets of irregular length (a cut may split an x from its y)."""
    data = raw.read_bytes()[read_header(raw).data_offset:]
    cuts = np.cumsum(RNG.integers(1, 4000, size=len(data) // 2)) * 2
    cuts = np.concatenate([[0], cuts[cuts < len(data)], [len(data)]])
    return [data[a:b] for a, b in zip(cuts[:-1], cuts[1:])]


def _mono_payloads(raw: Path) -> list[tuple[int, bytes]]:
    """(time_base_ns, payload) packets of ~0.1 s of the file's events in the ``mono`` layout."""
    x, y, t, p = (np.concatenate(c) for c in zip(*((c.x, c.y, c.t_us, c.p) for c in iter_events(raw))))
    out = []
    for lo in range(int(t[0]), int(t[-1]) + 1, 100_000):
        sel = (t >= lo) & (t < lo + 100_000)
        out.append((lo * 1000, codecs.encode_mono(x[sel], y[sel], t[sel] * 1000, p[sel], lo * 1000)))
    return out


def _write_bag(path: Path, flavour: str, encoding: str, raw: Path) -> None:
    ros2 = flavour != "ros1"
    store = make_typestore(ros2)
    T = store.types
    Time, Header = T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"]
    Packet = T["event_camera_msgs/msg/EventPacket"]

    def header(ns: int):
        stamp = Time(sec=ns // 10**9, nanosec=ns % 10**9)
        return Header(stamp=stamp, frame_id="cam") if ros2 else Header(seq=0, stamp=stamp, frame_id="cam")

    t0 = 1_700_000_000 * 10**9
    if encoding == "mono":
        packets = _mono_payloads(raw)
    else:
        packets = [(0, d) for d in _evt3_payloads(raw)]
    msgs = [(t0 + i * 1_000_000, Packet(header=header(t0 + i * 1_000_000), height=H, width=W, seq=i, time_base=tb,
                                        encoding=encoding,
                                        is_bigendian=False, events=np.frombuffer(d, np.uint8)))
            for i, (tb, d) in enumerate(packets)]
    PointField, PointCloud2 = T["sensor_msgs/msg/PointField"], T["sensor_msgs/msg/PointCloud2"]
    rec = np.zeros(len(POINTS), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4")])
    rec["x"], rec["y"], rec["z"] = POINTS.T
    rec["intensity"] = INTEN
    fields = [PointField(name=n, offset=4 * k, datatype=7, count=1) for k, n in enumerate(("x", "y", "z", "intensity"))]
    cloud = PointCloud2(header=header(t0), height=1, width=len(POINTS), fields=fields, is_bigendian=False,
                        point_step=16, row_step=16 * len(POINTS), data=np.frombuffer(rec.tobytes(), np.uint8),
                        is_dense=True)
    if ros2:
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugin = StoragePlugin.MCAP if flavour == "mcap" else StoragePlugin.SQLITE3
        writer, serialize = Writer(path, version=9, storage_plugin=plugin), store.serialize_cdr
    else:
        from rosbags.rosbag1 import Writer

        writer, serialize = Writer(path), store.serialize_ros1
    with writer:
        ev = writer.add_connection("/event_camera/events", "event_camera_msgs/msg/EventPacket", typestore=store)
        pc = writer.add_connection("/points", "sensor_msgs/msg/PointCloud2", typestore=store)
        writer.write(pc, t0 + 1, serialize(cloud, pc.msgtype))
        for t, m in msgs:
            writer.write(ev, t, serialize(m, ev.msgtype))


@pytest.mark.parametrize("flavour", ["sqlite3", "mcap", "ros1"])
@pytest.mark.parametrize("encoding", ["evt3", "mono"])
def test_extract_gives_the_raw_recordings_map(tmp_path: Path, raw_recording: Path, flavour: str, encoding: str) -> None:
    bag = tmp_path / ("rec.bag" if flavour == "ros1" else "rec")
    _write_bag(bag, flavour, encoding, raw_recording)
    topics = {t.name: t for t in list_topics(bag)}
    assert topics["/event_camera/events"].kind == "events"
    assert topics["/event_camera/events"].msgtype == "event_camera_msgs/msg/EventPacket"
    for start, window in ((0.0, 3.0), (1.5, 2.0)):  # the second window straddles the 2^24 us wrap
        out = tmp_path / f"out_{start}"
        scenes = extract_bag(bag, out, ExtractSettings(window_s=window, start_s=start))
        image, _ = load_map(scenes[0].map_path)
        expected = accumulate_events(raw_recording, window_s=window, start_s=start)
        assert image.shape == (H, W) and expected.sum() > 10_000
        np.testing.assert_array_equal(image, expected)
        assert scenes[0].points == len(POINTS)


def test_cli_extract_and_refused_encodings(tmp_path: Path, raw_recording: Path, capsys) -> None:
    bag = tmp_path / "rec"
    _write_bag(bag, "mcap", "evt3", raw_recording)
    assert main(["extract", str(bag), "--list"]) == 0
    assert "/event_camera/events" in capsys.readouterr().out
    assert main(["extract", str(bag), "--out", str(tmp_path / "out")]) == 0
    assert (tmp_path / "out" / "event" / "rec.png").is_file()
    trig = tmp_path / "trig.bag"
    _write_bag(trig, "ros1", "trigger", raw_recording)
    with pytest.raises(InputError, match=r"trig\.bag.*'trigger'.*not pixel events"):
        extract_bag(trig, tmp_path / "o")
    assert main(["extract", str(trig), "--out", str(tmp_path / "o2")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "trigger" in err[0] and "Traceback" not in err[0]


def test_libcaer_layout_and_rollover() -> None:
    """libcaer packets: x bits 31..17, y 16..2, polarity bit 1, int32 us; a time running
    backwards inside a packet is the counter's rollover (+2^31 us)."""
    x = np.array([0, 345, 17, 1000])
    y = np.array([259, 0, 100, 7])
    p = np.array([1, 0, 1, 0])
    t_us = np.array([2**31 - 20, 2**31 - 1, 5, 9])
    rec = np.zeros(4, [("d", "<u4"), ("t", "<i4")])
    rec["d"] = (x << 17) | (y << 2) | (p << 1) | 1  # bit 0: libcaer's "valid" mark
    rec["t"] = (t_us % 2**31).astype(np.int64)
    dx, dy, dt, dp = codecs.decode_libcaer(rec.tobytes(), 7_000_000)
    np.testing.assert_array_equal(dx, x)
    np.testing.assert_array_equal(dy, y)
    np.testing.assert_array_equal(dp, p)
    np.testing.assert_array_equal(dt, 7_000 + t_us + np.array([0, 0, 2**31, 2**31]))


def test_mono_layout() -> None:
    """mono words: polarity bit 63, y 62..48, x 47..32, ns after the time base in 31..0."""
    words = np.array([(1 << 63) | (719 << 48) | (1279 << 32) | 5_000, (3 << 48) | (2 << 32) | 4_000_000_000],
                     dtype=np.uint64)
    x, y, t, p = codecs.decode_mono(words.astype("<u8").tobytes(), 10**12)
    assert x.tolist() == [1279, 2] and y.tolist() == [719, 3] and p.tolist() == [1, 0]
    assert t.tolist() == [10**9 + 5, 10**9 + 4_000_000]
