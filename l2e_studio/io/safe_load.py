"""Reading small structured files (camera, seed, result files) with bounded memory and time.

* a size cap before anything is read (:data:`MAX_DOCUMENT_BYTES`);
* YAML without alias expansion bombs: an alias may only repeat a scalar, never a list or a
  mapping (a 634-byte "billion laughs" file otherwise expands to gigabytes downstream);
* ``.npy`` / ``.npz`` arrays whose headers are checked against the bytes the file holds
  before numpy allocates what they declare;
* bounded nesting for YAML and JSON (:data:`MAX_DEPTH`), checked before the recursive parsers
  run, so a 100k-level file is one :class:`InputError`, not a ``RecursionError`` traceback.
"""

from __future__ import annotations

import json
import re
import zipfile
import zlib
from pathlib import Path
from typing import Any

import yaml

from ..errors import InputError

#: Camera, seed and result files are a few kB; anything this large is not one.
MAX_DOCUMENT_BYTES = 4 * 1024 * 1024
#: Deeper than any camera/seed/result layout (they nest 4 levels at most).
MAX_DEPTH = 64


def read_text_capped(path: Path, limit: int = MAX_DOCUMENT_BYTES, what: str = "file") -> str:
    """The UTF-8 text of ``path``, refusing files larger than ``limit`` bytes before reading them."""
    if not path.is_file():
        raise InputError(path, f"{what} not found" if not path.exists() else f"{what} is not a regular file")
    size = path.stat().st_size
    if size > limit:
        raise InputError(path, f"{what} is {size / 2**20:.1f} MiB; a camera or seed file is at most "
                               f"{limit / 2**20:.0f} MiB")
    try:
        with path.open("rb") as fh:
            data = fh.read(limit + 1)
    except OSError as exc:
        raise InputError(path, f"cannot read ({exc.strerror or exc})") from None
    if len(data) > limit:  # grew while we looked
        raise InputError(path, f"{what} is larger than {limit / 2**20:.0f} MiB")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise InputError(path, "not a UTF-8 text file") from None


class _BoundedLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` with a nesting limit and aliases restricted to scalars."""

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self._depth = 0

    def compose_node(self, parent, index):  # type: ignore[override]
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            node = self.anchors.get(event.anchor)
            if node is not None and not isinstance(node, yaml.ScalarNode):
                raise _Refused(f"YAML alias *{event.anchor} repeats a list or mapping (line {event.start_mark.line + 1}); "
                               "aliases may only repeat single values")
            return super().compose_node(parent, index)
        self._depth += 1
        if self._depth > MAX_DEPTH:
            raise _Refused(f"nested more than {MAX_DEPTH} levels deep (line {self.peek_event().start_mark.line + 1})")
        try:
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


class _Refused(Exception):
    pass


def parse_yaml(path: Path, text: str) -> Any:
    """``yaml.safe_load`` with the bounds above; :class:`yaml.YAMLError` passes through for the caller."""
    loader = _BoundedLoader(text)
    try:
        return loader.get_single_data()
    except _Refused as exc:
        raise InputError(path, str(exc)) from None
    except RecursionError:  # pragma: no cover - the depth limit comes first
        raise InputError(path, f"nested more than {MAX_DEPTH} levels deep") from None
    finally:
        loader.dispose()


_JSON_STRING = re.compile(r'"(?:[^"\\]|\\.)*"', re.S)


def json_depth(text: str) -> int:
    """The deepest ``[``/``{`` nesting of JSON ``text`` (strings ignored), without parsing it."""
    depth = deepest = 0
    for ch in re.sub(r"[^\[\]{}]", "", _JSON_STRING.sub("", text)):
        depth += 1 if ch in "[{" else -1
        deepest = max(deepest, depth)
    return deepest


def parse_json(path: Path, text: str) -> Any:
    """``json.loads`` with the nesting bound; malformed JSON is one :class:`InputError` line."""
    depth = json_depth(text)
    if depth > MAX_DEPTH:
        raise InputError(path, f"JSON nested {depth} levels deep; at most {MAX_DEPTH} are accepted")
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(path, f"invalid JSON ({exc.msg} at line {exc.lineno})") from None


def load_npy(path: Path) -> "np.ndarray":
    """``np.load`` of a plain .npy after checking that the file holds the data its header declares
    (``np.load`` allocates the declared array first: a 200-byte file can ask for gigabytes)."""
    import numpy as np

    try:
        with path.open("rb") as fh:
            version = np.lib.format.read_magic(fh)
            read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
            shape, _, dtype = read_header(fh)
            available = path.stat().st_size - fh.tell()
    except (ValueError, OSError, EOFError) as exc:
        raise InputError(path, f"cannot read the .npy header ({exc})") from None
    declared = int(np.prod(shape, dtype=np.float64)) * dtype.itemsize
    if not dtype.hasobject and declared > available:
        raise InputError(path, f"the .npy header declares {shape} {dtype} ({declared} bytes) but the file holds "
                               f"{available} bytes of data")
    try:
        return np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise InputError(path, f"cannot read the .npy file ({str(exc).splitlines()[0]})") from None


#: Errors a damaged .npz raises while its members are read (zip framing, deflate stream, npy header).
NPZ_ERRORS = (zipfile.BadZipFile, zlib.error, ValueError, OSError, EOFError, KeyError, NotImplementedError)
#: Deflate expands at most 1032:1 (RFC 1951's longest match per code); a member declaring more
#: uncompressed bytes than that lies about its size.
DEFLATE_MAX_RATIO = 1032


def open_npz(path: Path) -> "np.lib.npyio.NpzFile":
    """``np.load`` of an .npz after checking that it is a zip archive of plain .npy arrays whose
    declared shapes fit the bytes each member holds (numpy allocates the declared array first).
    Reading a member later may still meet a damaged deflate stream: catch :data:`NPZ_ERRORS`."""
    import numpy as np

    if not zipfile.is_zipfile(path):
        raise InputError(path, "not an .npz file (not a zip archive of .npy arrays)")
    try:
        with zipfile.ZipFile(path) as zf:
            for info in zf.infolist():
                _check_npz_member(path, zf, info)
        return np.load(path, allow_pickle=False)
    except InputError:
        raise
    except NPZ_ERRORS as exc:
        raise InputError(path, f"damaged .npz archive ({_first_line(exc)})") from None


def _check_npz_member(path: Path, zf: zipfile.ZipFile, info: zipfile.ZipInfo) -> None:
    import numpy as np

    name = info.filename
    if not name.endswith(".npy"):
        raise InputError(path, f"the .npz member {name!r} is not a .npy array")
    if info.compress_type != zipfile.ZIP_STORED and info.file_size > DEFLATE_MAX_RATIO * info.compress_size + 1024:
        raise InputError(path, f"the .npz member {name!r} declares {info.file_size} bytes from {info.compress_size} "
                               "compressed ones, more than deflate can expand")
    with zf.open(info) as fh:
        version = np.lib.format.read_magic(fh)
        read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
        shape, _, dtype = read_header(fh)
        header_bytes = fh.tell()
    if dtype.hasobject:
        raise InputError(path, f"the .npz member {name!r} holds Python objects; only plain arrays are read")
    declared = int(np.prod(shape, dtype=np.float64)) * dtype.itemsize
    if declared > info.file_size - header_bytes:
        raise InputError(path, f"the .npz member {name!r} declares {shape} {dtype} ({declared} bytes) but holds "
                               f"{info.file_size - header_bytes} bytes of data")


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__
