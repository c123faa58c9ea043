"""How imu_dcm recognises the files it wrote, by their content (for :mod:`imu_dcm.outputs`).

An existing file is replaced only when it carries the signature this tool writes into its kind
of output; anything else is someone else's file and is refused. The signatures:

============  =========================================  ==================================
kind          what                                       signature (read from the start)
============  =========================================  ==================================
``json``      a summary (replay, live)                   first key ``"written_by": "imu_dcm …"``
``rrd``       a rerun recording (``--rerun save:``)      ``RRF`` magic, then the application
                                                         id ``imu_dcm`` in the store info
``tum``       a TUM trajectory (``--export-tum``)        first line ``# imu_dcm …``
``csv``       a CSV export                               first line ``# imu_dcm …``
``table``     the batch table (``--table OUT.csv``)      header row ``path,samples,
                                                         duration_s,rate_hz,imu_topic,…``
``markdown``  the batch table's ``OUT.md``               first line ``<!-- imu_dcm … -->``
``chart``     a PNG chart                                ``tEXt`` chunk ``Software`` =
                                                         ``imu_dcm …``, before the image data
``curves``    the batch curves (``OUT.curves.jsonl``)    first line an object of ``path``,
                                                         ``t_s``, ``error_deg``
``mcap``      an MCAP file                               header record's library
                                                         ``imu_dcm.bag_writer`` / ``imu_dcm.live``
============  =========================================  ==================================

``any`` accepts a file of any of these kinds. An empty file holds nothing to lose and counts as
replaceable. Only the first :data:`HEAD_BYTES` bytes of a file are read.
"""

from __future__ import annotations

import json
import os
import re
import struct
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from imu_dcm import __version__

__all__ = ["HEAD_BYTES", "KINDS", "TOOL", "Kind", "comment_line", "is_own", "signature"]

#: The name every signature starts with.
TOOL = "imu_dcm"
#: Bytes read from the start of a file to recognise it.
HEAD_BYTES = 64 * 1024
_MCAP_MAGIC = b"\x89MCAP0\r\n"
#: MCAP header ``library`` values of the project's bag writers (replay/convert-csv/data_synth,
#: and live's recorder).
OWN_MCAP_LIBRARIES = (b"imu_dcm.bag_writer", b"imu_dcm.live")
_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
#: The batch table's first columns (more may follow: the header is matched on these).
_TABLE_HEAD = ("path", "samples", "duration_s", "rate_hz", "imu_topic")
_JSON_SIGNED = re.compile(rb'\A\s*\{\s*"written_by"\s*:\s*"imu_dcm[ "]')


def signature(what: str) -> str:
    """``imu_dcm <version> <what>``: the text every signed output carries."""

    return f"{TOOL} {__version__} {what}"


def comment_line(what: str) -> str:
    """The first line of a signed text file (TUM, CSV export): ``# imu_dcm <version> <what>``."""
    return f"# {signature(what)}\n"


def _first_line(head: bytes) -> bytes:
    return head.split(b"\n", 1)[0].rstrip(b"\r")


def _json(head: bytes) -> bool:
    return _JSON_SIGNED.match(head) is not None


def _rrd(head: bytes) -> bool:
    # rerun's file header "RRF" + version digit, then protobuf messages whose store info holds
    # the application id as a length-prefixed string (viz and live both use "imu_dcm")
    return head[:3] == b"RRF" and b"\x07" + TOOL.encode() in head[:4096]


def _commented(head: bytes) -> bool:
    return _first_line(head).startswith(b"# " + TOOL.encode())


def _table(head: bytes) -> bool:
    cells = _first_line(head).decode("utf-8", "replace").split(",")
    return tuple(cells[: len(_TABLE_HEAD)]) == _TABLE_HEAD


def _markdown(head: bytes) -> bool:
    return _first_line(head).startswith(b"<!-- " + TOOL.encode())


def _png(head: bytes) -> bool:
    """A ``tEXt`` chunk ``Software`` naming this tool before the first ``IDAT``."""
    if not head.startswith(_PNG_MAGIC):
        return False
    pos = len(_PNG_MAGIC)
    while pos + 8 <= len(head):
        length, kind = struct.unpack_from(">I4s", head, pos)
        if kind == b"IDAT":
            return False
        data = head[pos + 8 : pos + 8 + length]
        if kind == b"tEXt" and data.startswith(b"Software\0" + TOOL.encode()):
            return True
        pos += 12 + length
    return False


def _figure(head: bytes) -> bool:
    """A PNG signed as :func:`_png`, or an SVG whose metadata (matplotlib's ``Creator``, near
    the top) names this tool."""
    if _png(head):
        return True
    top = head[:4096]
    return b"<svg" in top and b"<dc:title>" + TOOL.encode() in top


def _curves(head: bytes) -> bool:
    try:
        first = json.loads(_first_line(head))
    except ValueError:
        return False
    return isinstance(first, dict) and set(first) == {"path", "t_s", "error_deg"}


def _mcap(head: bytes) -> bool:
    return head.startswith(_MCAP_MAGIC) and any(lib in head[:256] for lib in OWN_MCAP_LIBRARIES)


@dataclass(frozen=True, slots=True)
class Kind:
    """A kind of output: how it is named in messages, how it is recognised, and whether an
    existing one of this tool's needs ``--force`` to be replaced (a batch table does: its rows
    are the result of a long run; a summary or a chart is simply written again)."""

    words: str
    recognise: Callable[[bytes], bool]
    needs_force: bool = False


KINDS: dict[str, Kind] = {
    "json": Kind("its JSON summary", _json),
    "rrd": Kind("its rerun recording", _rrd),
    "tum": Kind("its TUM file", _commented),
    "csv": Kind("its CSV export", _commented),
    "table": Kind("its batch table", _table, needs_force=True),
    "markdown": Kind("its markdown table", _markdown),
    "chart": Kind("its PNG chart", _png),
    "figure": Kind("its figure", _figure),
    "yaml": Kind("its noise YAML", _commented),
    "curves": Kind("its curves file", _curves),
    "mcap": Kind("its MCAP file", _mcap),
}


def is_own(path: str | Path, kind: str) -> bool:
    """True when the regular file ``path`` is empty or carries the signature of ``kind`` (or,
    for ``"any"``, of any kind). Unreadable files are not ours."""

    flags = os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOFOLLOW", 0)  # a swapped-in FIFO: no wait
    try:
        fd = os.open(path, flags)
        try:
            head = os.read(fd, HEAD_BYTES)
        finally:
            os.close(fd)
    except OSError:
        return False
    if not head:
        return True
    kinds = KINDS.values() if kind == "any" else (KINDS[kind],)
    return any(k.recognise(head) for k in kinds)
