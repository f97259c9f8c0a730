"""Scenes from ROS 1 / ROS 2 bags, without a ROS install (pure-Python ``rosbags``).

Event topics: ``dvs_msgs/EventArray`` (rpg_dvs_ros), ``prophesee_event_msgs/EventArray``
(prophesee_ros_wrapper) and ``event_camera_msgs/EventPacket`` (metavision_driver, libcaer_driver:
the camera's own encoding, decoded by :mod:`l2e_studio.io.event_packets`); their definitions are
registered in the typestore here. Lidar topics:
``sensor_msgs/PointCloud2`` (fields decoded with numpy; intensity field chosen by name).
A ``sensor_msgs/CameraInfo`` topic, when one is found, is written as ``camera.yaml``.

A scene is one bag, or one time slice of ``slice_s`` seconds of a bag (bag time): its event
map counts the events of ``[first event + start_s, + window_s)`` within the slice (the paper's
accumulated map), its scan is the first cloud of the slice (or ``scans`` consecutive clouds
merged, for a static scene). Output: ``OUT/event/<stem>.png`` + ``OUT/lidar/<stem>.pcd``.

ROS 1 EventArray payloads are decoded straight from their bytes with a numpy structured
dtype (13 bytes an event); ROS 2 (CDR, with alignment padding) goes through ``rosbags``'
deserialiser.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from ..atomic import atomic_write_bytes
from ..errors import InputError
from .event_packets import PACKET_TYPE, PacketError, PacketStream, packet_types

EVENT_MSG = """std_msgs/Header header
uint32 height
uint32 width
{pkg}/Event[] events
"""
EVENT_ELEM = """uint16 x
uint16 y
time ts
bool polarity
"""
EVENT_PACKAGES = ("dvs_msgs", "prophesee_event_msgs")
ARRAY_TYPES = tuple(f"{pkg}/msg/EventArray" for pkg in EVENT_PACKAGES)
EVENT_TYPES = (*ARRAY_TYPES, PACKET_TYPE)
CLOUD_TYPE = "sensor_msgs/msg/PointCloud2"
INFO_TYPE = "sensor_msgs/msg/CameraInfo"

_ROS1_EVENT = np.dtype([("x", "<u2"), ("y", "<u2"), ("sec", "<u4"), ("nsec", "<u4"), ("p", "u1")])
_PF_DTYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


def register_event_types(typestore) -> None:
    """Add the dvs_msgs and prophesee_event_msgs Event/EventArray and the event_camera_msgs
    EventPacket definitions to ``typestore``; a family the store already defines otherwise (a
    bag's own definitions) keeps its definition."""
    from rosbags.typesys import get_types_from_msg

    families = [{**get_types_from_msg(EVENT_ELEM, f"{pkg}/msg/Event"),
                 **get_types_from_msg(EVENT_MSG.format(pkg=pkg), f"{pkg}/msg/EventArray")} for pkg in EVENT_PACKAGES]
    for types in (*families, packet_types()):
        try:
            typestore.register(types)
        except Exception:  # rosbags' TypesysError: defined differently already
            pass


def make_typestore(ros2: bool = False):
    """A typestore with the standard messages plus the event arrays."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE if ros2 else Stores.ROS1_NOETIC)
    register_event_types(store)
    return store


@dataclass
class TopicInfo:
    name: str
    msgtype: str
    count: int

    @property
    def kind(self) -> str:
        if self.msgtype in EVENT_TYPES:
            return "events"
        if self.msgtype == CLOUD_TYPE:
            return "lidar"
        if self.msgtype == INFO_TYPE:
            return "camera_info"
        return "other"


#: How much a ROS 1 chunk may expand: LZ4 reaches at most 255:1; bz2 is given the same bound
#: (bags of sensor data compress a few times, never a thousand).
MAX_CHUNK_RATIO = 255


def check_ros1_records(path: Path) -> None:
    """Walk a ROS 1 bag's records (header length, header, data length, data) and refuse one
    that states more bytes than the file holds, or a chunk that claims to expand beyond
    :data:`MAX_CHUNK_RATIO` (the reader allocates what they state: a flipped byte asked for 832 MB)."""
    import struct

    size = path.stat().st_size
    with path.open("rb") as fh:
        if fh.readline(64) != b"#ROSBAG V2.0\n":
            return  # not a ROS 1 bag v2.0: the reader says what it is
        pos = fh.tell()
        while pos < size:
            head = fh.read(4)
            if len(head) < 4:
                raise InputError(path, f"the bag ends inside the record at byte {pos} (truncated?)")
            header_len = struct.unpack("<I", head)[0]
            if header_len > size - pos - 8:
                raise InputError(path, f"the record at byte {pos} states a {header_len}-byte header but the file "
                                       f"holds {size - pos - 4} more bytes (truncated or damaged bag)")
            header = fh.read(header_len)
            data_len = struct.unpack("<I", fh.read(4))[0]
            if data_len > size - pos - 8 - header_len:
                raise InputError(path, f"the record at byte {pos} states {data_len} bytes of data but the file "
                                       f"holds {size - pos - 8 - header_len} more (truncated or damaged bag)")
            fields = _ros1_fields(header)
            if fields.get("op") == b"\x05" and "size" in fields and len(fields["size"]) == 4:  # a chunk
                unpacked = struct.unpack("<I", fields["size"])[0]
                ratio = 1 if fields.get("compression", b"none") == b"none" else MAX_CHUNK_RATIO
                if unpacked > data_len * ratio + 1024:
                    raise InputError(path, f"the chunk at byte {pos} claims {unpacked} bytes from {data_len} "
                                           f"({fields.get('compression', b'none').decode('ascii', 'replace')})")
            pos = fh.seek(data_len, 1)


def _ros1_fields(header: bytes) -> dict[str, bytes]:
    """``name=value`` fields of a ROS 1 record header (each prefixed by its uint32 length)."""
    fields, i = {}, 0
    while i + 4 <= len(header):
        n = int.from_bytes(header[i:i + 4], "little")
        name, _, value = header[i + 4:i + 4 + n].partition(b"=")
        fields[name.decode("ascii", "replace")] = value
        i += 4 + n
    return fields


def _open(paths: Iterable[Path]):
    from rosbags.highlevel import AnyReader

    paths = [Path(p) for p in paths]
    for p in paths:
        if not p.exists():
            raise InputError(p, "bag not found")
        if p.is_file():
            check_ros1_records(p)
    store = make_typestore()
    try:
        reader = AnyReader(paths, default_typestore=store)
        reader.open()
    except Exception as exc:  # rosbags raises its own ReaderError/AnyReaderError types
        raise InputError(paths[0] if len(paths) == 1 else None,
                         f"cannot open as a ROS 1/2 bag ({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})") from None
    # Bags carry their own message definitions; make sure ours are known for ROS 2 bags without them.
    register_event_types(reader.typestore if hasattr(reader, "typestore") else store)
    return reader


def list_topics(bag: str | Path) -> list[TopicInfo]:
    """The topics of a bag with their message types and counts."""
    reader = _open([bag])
    try:
        return sorted((TopicInfo(name, t.msgtype or "", int(t.msgcount)) for name, t in reader.topics.items()),
                      key=lambda t: t.name)
    finally:
        reader.close()


@dataclass
class ExtractSettings:
    event_topic: str | None = None
    lidar_topic: str | None = None
    slice_s: float | None = None  # None: one scene per bag
    window_s: float = 3.0
    start_s: float | None = None
    scans: int = 1
    intensity_field: str | None = None
    width: int | None = None
    height: int | None = None


@dataclass
class ExtractedScene:
    name: str
    map_path: Path
    lidar_path: Path
    events: int
    points: int


@dataclass
class _Slice:
    chunks: list[tuple[np.ndarray, ...]] = field(default_factory=list)
    clouds: list[dict[str, np.ndarray]] = field(default_factory=list)
    size: tuple[int, int] | None = None


def pick_topics(topics: list[TopicInfo], settings: ExtractSettings, bag: Path) -> tuple[str, str]:
    """The event and lidar topics: the ones named, else the only one of each kind."""
    chosen = []
    for kind, wanted in (("events", settings.event_topic), ("lidar", settings.lidar_topic)):
        names = [t.name for t in topics if t.kind == kind]
        if wanted is not None:
            if wanted not in {t.name for t in topics}:
                raise InputError(bag, f"no topic {wanted}; topics: {_describe(topics)}")
            chosen.append(wanted)
        elif len(names) == 1:
            chosen.append(names[0])
        else:
            flag = "--event-topic" if kind == "events" else "--lidar-topic"
            what = "several" if names else "no"
            raise InputError(bag, f"{what} {kind} topics; choose one with {flag}. Topics: {_describe(topics)}")
    return chosen[0], chosen[1]


def _describe(topics: list[TopicInfo]) -> str:
    return "; ".join(f"{t.name} [{t.msgtype}, {t.count}]" for t in topics) or "none"


def extract_bag(
    bag: str | Path,
    out: str | Path,
    settings: ExtractSettings = ExtractSettings(),
    on_progress: Callable[[int, int], None] | None = None,
) -> list[ExtractedScene]:
    """Write the scenes of one bag into ``out`` (``event/``, ``lidar/``, maybe ``camera.yaml``)."""
    from .lidar import _finish
    from .maps import write_map_png

    bag, out = Path(bag), Path(out)
    reader = _open([bag])
    try:
        topics = [TopicInfo(name, t.msgtype or "", int(t.msgcount)) for name, t in reader.topics.items()]
        ev_topic, pc_topic = pick_topics(topics, settings, bag)
        info_topics = [t.name for t in topics if t.kind == "camera_info"]
        conns = [c for c in reader.connections if c.topic in (ev_topic, pc_topic, *info_topics[:1])]
        total = sum(t.count for t in topics if t.name in (ev_topic, pc_topic))
        t_begin = reader.start_time
        slices: dict[int, _Slice] = {}
        done = 0
        camera_info = None
        packets = PacketStream(ev_topic)
        for conn, stamp, raw in reader.messages(connections=conns):
            if conn.topic in info_topics:
                if camera_info is None:
                    camera_info = reader.deserialize(raw, conn.msgtype)
                continue
            index = 0 if not settings.slice_s else int((stamp - t_begin) // int(settings.slice_s * 1e9))
            sl = slices.setdefault(index, _Slice())
            if conn.topic == ev_topic:
                try:
                    x, y, t, p, size = _decode_events(reader, conn, raw, packets)
                except PacketError as exc:
                    raise InputError(bag, str(exc)) from None
                sl.chunks.append((x, y, t, p))
                sl.size = sl.size or size
            elif len(sl.clouds) < settings.scans:
                sl.clouds.append(_decode_cloud(bag, reader.deserialize(raw, conn.msgtype)))
            done += 1
            if on_progress is not None:
                on_progress(done, total)
    except InputError:
        raise
    except Exception as exc:  # rosbags' reader errors on truncated/corrupt bags
        raise InputError(bag, f"cannot read the bag ({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})") from None
    finally:
        reader.close()
    scenes = []
    for index in sorted(slices):
        sl = slices[index]
        stem = bag.name.split(".")[0] if not settings.slice_s else f"{bag.name.split('.')[0]}_{index:04d}"
        if not sl.chunks or not sl.clouds:
            continue
        image, n_events = _accumulate(bag, sl, settings)
        merged = {k: np.concatenate([c[k] for c in sl.clouds if k in c]) for k in sl.clouds[0]}
        scan = _finish(bag, merged, settings.intensity_field)
        if not scan.has_intensity:  # an all-zero field would look like a scan and calibrate nothing
            raise InputError(bag, f"the point clouds have no intensity field (fields: {', '.join(merged)}); "
                                  "pass --intensity-field NAME")
        map_path = write_map_png(out / "event" / f"{stem}.png", image)
        lidar_path = write_lidar_pcd(out / "lidar" / f"{stem}.pcd", scan.points, scan.intensity)
        scenes.append(ExtractedScene(stem, map_path, lidar_path, n_events, len(scan)))
    if not scenes:
        raise InputError(bag, "no slice has both events and a point cloud")
    if camera_info is not None and not (out / "camera.yaml").exists():
        write_camera_yaml(out / "camera.yaml", camera_info)
    return scenes


def _decode_events(reader, conn, raw: bytes, packets: PacketStream):
    """(x, y, t_us, p, (width, height)) of one EventArray or EventPacket message."""
    if conn.msgtype == PACKET_TYPE:
        msg = reader.deserialize(raw, conn.msgtype)
        x, y, t, p = packets.decode(msg)
        return x, y, t, p, ((int(msg.width), int(msg.height)) if msg.width and msg.height else None)
    if not getattr(reader, "is2", False):
        # ROS 1: header (seq, stamp, frame_id), height, width, events[] of 13-byte records.
        off = 12
        flen = int.from_bytes(raw[off:off + 4], "little")
        off += 4 + flen
        height, width, n = np.frombuffer(raw, "<u4", 3, off)
        off += 12
        ev = np.frombuffer(raw, _ROS1_EVENT, int(n), off)
        t = ev["sec"].astype(np.int64) * 1_000_000 + ev["nsec"].astype(np.int64) // 1000
        size = (int(width), int(height)) if width and height else None
        return ev["x"].copy(), ev["y"].copy(), t, (ev["p"] > 0).astype(np.uint8), size
    msg = reader.deserialize(raw, conn.msgtype)
    evs = msg.events
    n = len(evs)
    x = np.fromiter((e.x for e in evs), np.uint16, n)
    y = np.fromiter((e.y for e in evs), np.uint16, n)
    t = np.fromiter((e.ts.sec * 1_000_000 + e.ts.nanosec // 1000 for e in evs), np.int64, n)
    p = np.fromiter((e.polarity for e in evs), np.uint8, n)
    size = (int(msg.width), int(msg.height)) if msg.width and msg.height else None
    return x, y, t, p, size


def _accumulate(bag: Path, sl: _Slice, s: ExtractSettings) -> tuple[np.ndarray, int]:
    from .events import _Counter

    t_all_first = min(int(c[2].min()) for c in sl.chunks if c[2].size)
    begin = t_all_first + int(round((s.start_s or 0.0) * 1e6))
    end = begin + int(round(s.window_s * 1e6))
    size = (s.width, s.height) if s.width and s.height else sl.size
    counter = _Counter(size)
    for x, y, t, _ in sl.chunks:
        counter.add_window(x, y, t, begin, end)
    if counter.total == 0:
        raise InputError(bag, "no events inside the accumulation window")
    return np.clip(counter.grid, 0, 127).astype(np.float32), counter.total


def _decode_cloud(bag: Path, msg) -> dict[str, np.ndarray]:
    """Named float columns of a sensor_msgs/PointCloud2."""
    order = ">" if msg.is_bigendian else "<"
    names, formats, offsets = [], [], []
    for f in msg.fields:
        code = _PF_DTYPES.get(int(f.datatype))
        if code is None:
            raise InputError(bag, f"PointCloud2 field {f.name!r} has unknown datatype {f.datatype}")
        names.append(f.name)
        formats.append(order + code if int(f.count) <= 1 else (order + code, (int(f.count),)))
        offsets.append(int(f.offset))
    dt = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": int(msg.point_step)})
    data = np.asarray(msg.data, dtype=np.uint8).tobytes()
    h, w = int(msg.height), int(msg.width)
    if int(msg.row_step) == w * int(msg.point_step):
        arr = np.frombuffer(data, dt, h * w)
    else:
        arr = np.concatenate([np.frombuffer(data, dt, w, r * int(msg.row_step)) for r in range(h)])
    return {n: np.asarray(arr[n], dtype=np.float64).reshape(arr.shape[0], -1)[:, 0] for n in names}


def write_lidar_pcd(path: str | Path, points: np.ndarray, intensity: np.ndarray) -> Path:
    """A binary PCD with float32 x, y, z, intensity (what PCL and our reader read)."""
    path = Path(path)
    n = int(points.shape[0])
    rec = np.zeros(n, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4")])
    rec["x"], rec["y"], rec["z"] = np.asarray(points, np.float32).T
    rec["intensity"] = intensity
    header = (f"# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z intensity\nSIZE 4 4 4 4\n"
              f"TYPE F F F F\nCOUNT 1 1 1 1\nWIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary\n")
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, header.encode("ascii") + rec.tobytes())
    return path


def write_camera_yaml(path: Path, info) -> Path:
    """Our camera.yaml from a sensor_msgs/CameraInfo (no seed: the user supplies one)."""
    import yaml

    K = np.asarray(info.K if hasattr(info, "K") else info.k, dtype=float).reshape(3, 3)
    D = [float(v) for v in (info.D if hasattr(info, "D") else info.d)]
    model = "equidistant" if str(info.distortion_model).lower() in ("equidistant", "fisheye") else "radtan"
    if model == "radtan" and len(D) not in (4, 5, 8):
        D = (D + [0.0] * 5)[:5]
    doc = {"camera": {"model": model, "width": int(info.width), "height": int(info.height),
                      "K": K.tolist(), "D": D}}
    atomic_write_bytes(path, ("# written by l2e-studio extract from a sensor_msgs/CameraInfo topic; add a seed: section\n"
                              + yaml.safe_dump(doc, sort_keys=False)).encode())
    return path
