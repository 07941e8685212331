"""A CRC for MCAP metadata records, which the format gives none.

MCAP protects chunks (``uncompressed_crc``), attachments (``crc``) and the summary (``summary_crc``), but a
metadata record is covered only by the data-section CRC, which a reader checks only by reading the whole file
(``gvt log info --verify``). gvtlink's metadata carries data — calibration, the time origin, the stream
summary, the timeline's offsets — so the writer adds one key, ``gvtlink.crc32``, the CRC-32 of the record's
name and its other entries in a canonical order, and every read checks it: a flipped byte in a metadata record
is damage on every path, not a silently different calibration. Records without the key (logs written before,
other tools' records) read as they are.
"""

from __future__ import annotations

import zlib
from collections.abc import Mapping

CRC_KEY = "gvtlink.crc32"


def _crc(name: str, data: Mapping[str, str]) -> str:
    canon = "\x00".join([name, *(f"{k}\x01{v}" for k, v in sorted(data.items()) if k != CRC_KEY)])
    return f"{zlib.crc32(canon.encode('utf-8', 'surrogatepass')):08x}"


def seal(name: str, data: Mapping[str, str]) -> dict[str, str]:
    """``data`` with its CRC key added (what the writer stores)."""
    out = {k: v for k, v in data.items() if k != CRC_KEY}
    out[CRC_KEY] = _crc(name, out)
    return out


def unseal(name: str, data: Mapping[str, str]) -> tuple[dict[str, str], bool]:
    """(``data`` without the CRC key, whether it passed); a record without the key passes (not sealed)."""
    body = {k: v for k, v in data.items() if k != CRC_KEY}
    if CRC_KEY not in data:
        return body, True
    return body, data[CRC_KEY] == _crc(name, body)
