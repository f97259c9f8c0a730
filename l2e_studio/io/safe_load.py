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
import struct
import tokenize
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


#: Errors numpy raises on a damaged .npy header (its dict is parsed with ``ast``/``tokenize``).
NPY_HEADER_ERRORS = (ValueError, OSError, EOFError, SyntaxError, tokenize.TokenError, struct.error)


def read_npy_header(fh, available: int) -> tuple[tuple[int, ...], "np.dtype", int]:
    """(shape, dtype, header bytes) of the .npy stream ``fh`` holding ``available`` bytes, after
    checking the header's own length against them (numpy reads whatever length the header
    states, and a flipped byte there asks for gigabytes)."""
    import numpy as np

    start = fh.read(12)
    if len(start) < 10 or start[:6] != b"\x93NUMPY":
        raise ValueError("not a .npy array (no \\x93NUMPY magic)")
    major = start[6]
    if major not in (1, 2, 3):
        raise ValueError(f"unknown .npy format version {major}.{start[7]}")
    length = struct.unpack("<H", start[8:10])[0] + 10 if major == 1 else struct.unpack("<I", start[8:12])[0] + 12
    if length > min(available, 1 << 20):
        raise ValueError(f"the .npy header claims {length} bytes but the data holds {available}")
    fh.seek(0)
    np.lib.format.read_magic(fh)
    read_header = np.lib.format.read_array_header_1_0 if major == 1 else np.lib.format.read_array_header_2_0
    shape, _, dtype = read_header(fh)
    return shape, dtype, length


def check_npy_size(path: Path, shape: tuple[int, ...], dtype: "np.dtype", available: int, what: str = "the .npy header") -> None:
    """Refuse a header declaring more data than the ``available`` bytes, or Python objects."""
    import numpy as np

    if dtype.hasobject:
        raise InputError(path, f"{what} declares Python objects; only plain arrays are read")
    if any(n < 0 for n in shape):
        raise InputError(path, f"{what} declares a negative shape {shape}")
    declared = int(np.prod(shape, dtype=np.float64)) * dtype.itemsize
    if declared > available:
        raise InputError(path, f"{what} declares {shape} {dtype} ({declared} bytes) but the file holds "
                               f"{available} bytes of data")


def load_npy(path: Path, mmap: bool = False) -> "np.ndarray":
    """``np.load`` of a plain .npy after checking that the file holds the data its header declares
    (``np.load`` allocates the declared array first: a 200-byte file can ask for gigabytes);
    ``mmap`` maps it read-only instead of reading it."""
    import numpy as np

    try:
        size = path.stat().st_size
        with path.open("rb") as fh:
            shape, dtype, length = read_npy_header(fh, size)
    except NPY_HEADER_ERRORS as exc:
        raise InputError(path, f"cannot read the .npy header ({_first_line(exc)})") from None
    check_npy_size(path, shape, dtype, size - length)
    try:
        return np.load(path, mmap_mode="r" if mmap else None, allow_pickle=False)
    except NPY_HEADER_ERRORS as exc:
        raise InputError(path, f"cannot read the .npy file ({_first_line(exc)})") from None


#: Errors a damaged .npz raises while its members are read (zip framing, deflate stream, npy header).
NPZ_ERRORS = (zipfile.BadZipFile, zlib.error, KeyError, NotImplementedError, RuntimeError, *NPY_HEADER_ERRORS)
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
    name = info.filename
    if not name.endswith(".npy"):
        raise InputError(path, f"the .npz member {name!r} is not a .npy array")
    if info.compress_type != zipfile.ZIP_STORED and info.file_size > DEFLATE_MAX_RATIO * info.compress_size + 1024:
        raise InputError(path, f"the .npz member {name!r} declares {info.file_size} bytes from {info.compress_size} "
                               "compressed ones, more than deflate can expand")
    with zf.open(info) as fh:
        shape, dtype, length = read_npy_header(fh, info.file_size)
    check_npy_size(path, shape, dtype, info.file_size - length, f"the .npz member {name!r}")


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__
