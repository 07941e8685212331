"""A UFF file split into its datasets, and dataset 58 (function at a nodal DOF) parsed: ASCII and binary 58b.

Why not pyuff alone for 58: other tools write dataset 58 in ways pyuff's fixed-width reader misreads or refuses --
short last rows, free-format rows of any width, Fortran ``D`` exponents -- and pyuff unpacks binary data value by
value (``struct.unpack``), far below the 50 M samples/s issue 31 asks. The layout is the I-DEAS universal file
reference (https://www.ceas3.uc.edu/sdrluff/, mirrored in pyuff's ``get_structure_58``): records 1-5 ID lines,
6 the DOF identification, 7 the data form (ordinate type 2/4 real single/double, 5/6 complex single/double, the
number of points, even or uneven abscissa), 8-11 the abscissa / ordinate / denominator / z axis (specific data
type, unit exponents, label, unit label), then the data: ASCII rows, or in 58b the header line's byte count of
raw values (byte order 1 little-, 2 big-endian). Every other dataset (15, 55, 82, 164, 1858) is read by pyuff.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from daq.studies.importing.data import ImportError_

DELIM = b"    -1"


@dataclass
class Block:
    """One dataset: its ``type``, whether binary (``58b``), its text or bytes after the type line, and its number in
    the file (1 = the first), which every message names."""

    type: int
    binary: bool
    head: bytes  # the type line itself (58b: byte order, format, ASCII lines, bytes)
    raw: bytes  # the whole file: a block is a range of it, so a 58b data block is read in place, never copied
    start: int
    end: int
    number: int

    @property
    def body(self) -> bytes:
        return self.raw[self.start : self.end]


def _is_delim(line: bytes) -> bool:
    return line.rstrip() == DELIM or line.strip() == b"-1"


def split_blocks(raw: bytes, where: str) -> list[Block]:
    """Every dataset of ``raw``, in order; ImportError_ for a file that is not UFF or is cut short."""
    blocks: list[Block] = []
    pos, n = 0, len(raw)
    while True:
        while pos < n and raw[pos : pos + 1] in (b"\n", b"\r", b" ") and raw[pos : pos + 6] != DELIM:
            pos += 1  # blank lines between datasets
        if pos >= n:
            return blocks
        line, pos = _line(raw, pos)
        if not _is_delim(line):
            what = "does not start with a UFF dataset ('    -1')" if not blocks else "has text between datasets"
            raise ImportError_(f"{where}: {what} (after dataset {len(blocks)}); not a UFF file, or a damaged one")
        if pos >= n:
            raise ImportError_(f"{where}: truncated: a '-1' line without a dataset at the end (after dataset {len(blocks)})")
        head, pos = _line(raw, pos)
        if pos > n:
            raise ImportError_(f"{where}: truncated: dataset {len(blocks) + 1} ends in its type line")
        try:
            kind = int(head[:6])
        except ValueError:
            raise ImportError_(f"{where}: dataset {len(blocks) + 1}: type line {head[:20]!r} is not a dataset number") from None
        binary = head[6:7].lower() == b"b"
        start = pos
        if binary:
            pos = end = _skip_binary(raw, head, pos, where, len(blocks) + 1)
            line, pos = _line(raw, pos)
            if not _is_delim(line):
                raise ImportError_(f"{where}: dataset {len(blocks) + 1} (58b): no '-1' after its {end - start} bytes; "
                                   "the byte count in its header is wrong or the file is damaged")  # fmt: skip
        else:
            end = _find_delim(raw, pos)
            if end < 0:
                raise ImportError_(f"{where}: truncated: dataset {len(blocks) + 1} (type {kind}) has no closing '-1'")
            pos = _line(raw, end)[1]
        blocks.append(Block(kind, binary, head, raw, start, end, len(blocks) + 1))


def _line(raw: bytes, pos: int) -> tuple[bytes, int]:
    end = raw.find(b"\n", pos)
    end = len(raw) if end < 0 else end
    return raw[pos:end].rstrip(b"\r"), end + 1


def _find_delim(raw: bytes, pos: int) -> int:
    """Start of the next line that is ``    -1`` at or after ``pos`` (-1 when none)."""
    while True:
        k = raw.find(DELIM, pos)
        if k < 0:
            return -1
        at_start = k == 0 or raw[k - 1 : k] == b"\n"
        rest = raw[k + 6 : raw.find(b"\n", k) if raw.find(b"\n", k) >= 0 else len(raw)]
        if at_start and not rest.strip():
            return k
        pos = k + 1


def binary_header(head: bytes, where: str) -> tuple[str, int, int]:
    """A 58b type line: (numpy byte order, ASCII header lines, data bytes)."""
    parts = head[7:].split()
    if len(parts) < 4:
        raise ImportError_(f"{where}: 58b type line {head.decode(errors='replace')!r} lacks byte order, format, "
                           "lines and bytes")  # fmt: skip
    order, _fmt, lines, nbytes = (int(p) for p in parts[:4])
    return ("<" if order == 1 else ">"), lines, nbytes


def _skip_binary(raw: bytes, head: bytes, pos: int, where: str, number: int) -> int:
    """End of a 58b dataset's data: its header's byte count, or -- where that does not end on a ``-1`` line -- the
    size record 7 gives (points x values x bytes). pyuff (2.5) writes the byte count of complex data as if it were
    real, half the size; its own reader never looks at it, so such files exist wherever pyuff wrote FRFs."""
    _bo, lines, nbytes = binary_header(head, f"{where}: dataset {number}")
    rec7 = b""
    for k in range(lines):
        if pos >= len(raw):
            break
        line, pos = _line(raw, pos)
        rec7 = line if k == 6 else rec7
    for size in dict.fromkeys((nbytes, _record7_bytes(rec7))):
        if size is not None and pos + size <= len(raw) and _is_delim(_line(raw, pos + size)[0]):
            return pos + size
    if pos + nbytes > len(raw):
        raise ImportError_(f"{where}: truncated: dataset {number} (58b) needs {nbytes} data bytes, the file has "
                           f"{max(0, len(raw) - pos)}")  # fmt: skip
    return pos + nbytes


def _record7_bytes(rec7: bytes) -> int | None:
    """Data bytes record 7 implies (ordinate type 2/4/5/6, points, even or uneven abscissa); None if unreadable."""
    try:
        t, n, spacing = (int(x) for x in rec7.split()[:3])
        return _expected({"ord_data_type": t, "num_pts": n, "abscissa_spacing": spacing})[0] * (4 if t in (2, 5) else 8)
    except ValueError:
        return None


# --- dataset 58 ----------------------------------------------------------------------------------------------
_REC6 = ((0, 5, "func_type"), (5, 15, "func_id"), (15, 20, "ver_num"), (20, 30, "load_case_id"),
         (31, 41, "rsp_ent_name"), (41, 51, "rsp_node"), (51, 55, "rsp_dir"), (56, 66, "ref_ent_name"),
         (66, 76, "ref_node"), (76, 80, "ref_dir"))  # fmt: skip
_AXES = ("abscissa", "ordinate", "orddenom", "z_axis")


def _int(text: bytes | str, what: str, where: str) -> int:
    try:
        return int(float(text))
    except ValueError:
        raise ImportError_(f"{where}: {what} {text!r} is not a number") from None


def _rec6(line: str, where: str) -> dict:
    d: dict = {}
    for a, b, key in _REC6:
        text = line[a:b].strip()
        d[key] = text if key.endswith("ent_name") else _int(text or "0", f"record 6 {key}", where)
    return d


def _axis(line: str, prefix: str, where: str) -> dict:
    nums = line[:25].split()
    if len(nums) < 4:
        raise ImportError_(f"{where}: {prefix} axis record {line!r} lacks its data type and unit exponents")
    spec, le, fe, te = (_int(x, f"{prefix} axis field", where) for x in nums[:4])
    return {f"{prefix}_spec_data_type": spec, f"{prefix}_len_unit_exp": le, f"{prefix}_force_unit_exp": fe,
            f"{prefix}_temp_unit_exp": te, f"{prefix}_axis_lab": line[25:46].strip(),
            f"{prefix}_axis_units_lab": line[46:67].strip()}  # fmt: skip


def parse_58(block: Block, where: str) -> dict:
    """Dataset 58 as pyuff names its fields (``x``, ``data`` and the header's), data as float64 / complex128."""
    at = f"{where}: dataset {block.number} (58{'b' if block.binary else ''})"
    text_end = _nth_line_end(block.raw, block.start, block.end, 11)
    lines = block.raw[block.start : text_end].decode("latin-1").splitlines()
    if len(lines) < 11:
        raise ImportError_(f"{at}: truncated: {len(lines)} of its 11 header records")
    d = {"type": 58, "binary": int(block.binary), **{f"id{k + 1}": lines[k].strip() for k in range(5)}}
    d.update(_rec6(lines[5].ljust(80), at))
    rec7 = lines[6].replace("D", "E").split()
    if len(rec7) < 5:
        raise ImportError_(f"{at}: record 7 {lines[6]!r} lacks the data type, points, spacing, start and step")
    d.update(ord_data_type=_int(rec7[0], "ordinate data type", at), num_pts=_int(rec7[1], "number of points", at),
             abscissa_spacing=_int(rec7[2], "abscissa spacing", at), abscissa_min=float(rec7[3]),
             abscissa_inc=float(rec7[4]))  # fmt: skip
    for prefix, line in zip(_AXES, lines[7:11], strict=True):
        d.update(_axis(line.ljust(67), prefix, at))
    values = _values(block, d, text_end, at)
    _unpack(d, values)
    return d


def _nth_line_end(raw: bytes, start: int, end: int, n: int) -> int:
    pos = start
    for _ in range(n):
        k = raw.find(b"\n", pos, end)
        if k < 0:
            return end
        pos = k + 1
    return pos


def _expected(d: dict) -> tuple[int, int]:
    """(values the data block holds, bytes per value) by record 7."""
    t = d["ord_data_type"]
    if t not in (2, 4, 5, 6):
        raise ValueError(f"ordinate data type {t}: not 2, 4 (real single/double) or 5, 6 (complex)")
    per = (2 if t in (5, 6) else 1) + (0 if d["abscissa_spacing"] == 1 else 1)
    return per * d["num_pts"], (4 if t in (2, 5) else 8)


def _values(block: Block, d: dict, first: int, at: str) -> np.ndarray:
    try:
        n, size = _expected(d)
    except ValueError as exc:
        raise ImportError_(f"{at}: {exc}") from None
    if block.binary:
        order, _lines, _nbytes = binary_header(block.head, at)
        if block.end - first < n * size:
            raise ImportError_(f"{at}: truncated: {(block.end - first) // size} of {n} values")
        values = np.frombuffer(block.raw, dtype=f"{order}f{size}", count=n, offset=first)
        return values.astype(float, copy=False)  # float64 in the machine's order: the file's bytes, not a copy
    return _ascii_values(block.raw[first : block.end], n, size, at)


def _ascii_values(data: bytes, n: int, size: int, at: str) -> np.ndarray:
    """Rows of any width, short or long, blank-separated, Fortran ``D`` exponents allowed; fields written edge to
    edge (a negative value filling its whole field) are read at the format's fixed width (E13.5 or E20.12)."""
    text = data.replace(b"D", b"E").replace(b"d", b"e")
    try:
        v = np.array(text.split(), dtype=float)
    except ValueError:
        v = np.zeros(0)
    if v.size != n:
        w = 13 if size == 4 else 20
        try:
            v = np.array([float(r[i:i + w]) for r in text.splitlines() for i in range(0, len(r.rstrip()), w)
                          if r[i:i + w].strip()], dtype=float)  # fmt: skip
        except ValueError:
            raise ImportError_(f"{at}: a data row holds text that is not a number") from None
    if v.size < n:
        raise ImportError_(f"{at}: truncated: {v.size} of {n} values")
    if v.size > n:
        raise ImportError_(f"{at}: {v.size} values where record 7 says {n}; the record's point count is wrong")
    return v


def _unpack(d: dict, v: np.ndarray) -> None:
    cplx, even, n = d["ord_data_type"] in (5, 6), d["abscissa_spacing"] == 1, d["num_pts"]
    if even:  # a time history's axis is its start and step (the import needs no array of it)
        d["x"] = None if d["func_type"] == 1 else d["abscissa_min"] + np.arange(n) * d["abscissa_inc"]
        d["data"] = v[0::2] + 1j * v[1::2] if cplx else v
    elif cplx:
        d["x"], d["data"] = v[0::3], v[1::3] + 1j * v[2::3]
    else:
        d["x"], d["data"] = v[0::2], v[1::2]


def parse_other(block: Block) -> dict | None:
    """A dataset pyuff reads (15, 18, 55, 82, 151, 164, 1858, 24xx) as pyuff's dict; None for one it does not."""
    from pyuff import pyuff as p

    fn = getattr(p, f"_extract{block.type}", None)
    if fn is None:
        return None
    text = (DELIM + b"\n" + block.head + b"\n" + block.body).decode("latin-1")
    return fn(text)


__all__ = ["Block", "binary_header", "parse_58", "parse_other", "split_blocks"]
