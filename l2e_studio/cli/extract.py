"""``l2e-studio extract BAG... --out DIR``: scenes from ROS 1 / ROS 2 bags, no ROS needed.

Reads dvs_msgs/EventArray, prophesee_event_msgs/EventArray or event_camera_msgs/EventPacket
(metavision_driver / libcaer_driver; encodings evt3, mono, libcaer) (``--event-topic``) and
sensor_msgs/PointCloud2 (``--lidar-topic``); when a bag has exactly one topic of a kind it is
used, otherwise the topics are listed and the command asks for a choice. Writes
``DIR/event/<stem>.png`` (accumulated map: every event over ``--window`` s, clipped to 127)
and ``DIR/lidar/<stem>.pcd``, one scene per bag or, with ``--slice S``, one per S seconds of
bag time; a CameraInfo topic becomes ``DIR/camera.yaml``. ``--list`` only lists the topics.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import InputError

NAME = "extract"
HELP = "Extract scenes (event map + lidar scan) from ROS 1/ROS 2 bags without a ROS install"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bags", nargs="+", type=Path, metavar="BAG", help="ROS 1 .bag files or ROS 2 bag folders")
    parser.add_argument("--out", type=Path, metavar="DIR", help="scene folder to write (event/, lidar/)")
    parser.add_argument("--list", action="store_true", help="list the topics of each bag and exit")
    parser.add_argument("--event-topic", metavar="TOPIC", help="dvs_msgs / prophesee_event_msgs EventArray or event_camera_msgs EventPacket "
                             "(evt3, mono, libcaer) topic")
    parser.add_argument("--lidar-topic", metavar="TOPIC", help="sensor_msgs/PointCloud2 topic")
    parser.add_argument("--slice", type=float, default=None, metavar="S",
                        help="one scene per S seconds of bag time (default: one scene per bag)")
    parser.add_argument("--window", type=float, default=3.0, metavar="S", help="event accumulation window, s (default 3)")
    parser.add_argument("--start", type=float, default=None, metavar="S", help="window start after the slice's first event, s")
    parser.add_argument("--scans", type=int, default=1, metavar="K", help="merge the first K clouds of a scene (default 1)")
    parser.add_argument("--intensity-field", metavar="NAME", help="PointCloud2 field to use as intensity")
    parser.add_argument("--size", metavar="WxH", help="event sensor size when the messages do not state it")


def run(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
    from rich.table import Table

    from ..io.bags import ExtractSettings, extract_bag, list_topics
    from ..io.events import parse_size

    console = Console()
    if args.list or args.out is None:
        for bag in args.bags:
            table = Table(title=str(bag))
            for col in ("topic", "type", "messages", "use as"):
                table.add_column(col)
            for t in list_topics(bag):
                table.add_row(t.name, t.msgtype, str(t.count), {"events": "--event-topic", "lidar": "--lidar-topic",
                                                                 "camera_info": "camera.yaml"}.get(t.kind, ""))
            console.print(table)
        if not args.list:
            raise InputError(None, "give --out DIR to extract scenes (topics listed above)")
        return 0
    from ..limits import MAX_WINDOW_S, require_range

    require_range("--window", args.window, 0.0, MAX_WINDOW_S, low_inclusive=False)
    require_range("--start", args.start, 0.0, MAX_WINDOW_S)
    require_range("--slice", args.slice, 0.0, MAX_WINDOW_S, low_inclusive=False)
    require_range("--scans", args.scans, 1, 1000)
    from .outputs import check_output_dir

    check_output_dir(args.out)
    width, height = parse_size(args.size) if args.size else (None, None)
    settings = ExtractSettings(args.event_topic, args.lidar_topic, args.slice, args.window, args.start,
                               max(1, args.scans), args.intensity_field, width, height)
    written = []
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                  console=console, transient=True) as progress:
        for bag in args.bags:
            task = progress.add_task(bag.name, total=None)
            scenes = extract_bag(bag, args.out, settings,
                                 on_progress=lambda done, total, task=task: progress.update(task, completed=done, total=total))
            written += scenes
    for s in written:
        console.print(f"{s.name}: {s.events} events -> {s.map_path}, {s.points} points -> {s.lidar_path}")
    console.print(f"{len(written)} scene(s) written to {args.out}")
    return 0
