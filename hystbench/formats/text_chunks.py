"""A UTF-8 text file as chunks of whole lines, in bounded memory, each with its first line number.

Why: a 60 s recording at 100 kS/s is ~600 MB of CSV; holding it as one string (plus the copies
that decoding, line-end conversion and parsing make) costs several times that.  Reading whole
lines a bounded block at a time keeps the text in memory to about one block, and line numbers
stay exact, so an error can still name the line.

A line longer than :data:`MAX_LINE_BYTES` is refused before more of it is read: without a
bound, a file with no line end (a 2 GB header field) was held whole, three times over, only to be
refused by the CSV parser.

Line ends are LF, CR LF or a lone CR (old spreadsheets), all given as LF; a UTF-8 BOM at the
start of the file is dropped.  A block is cut only after a line end, and no UTF-8 sequence
contains the bytes of CR or LF, so every chunk decodes on its own.
"""

from __future__ import annotations

from typing import BinaryIO, Iterator

from ..errors import RecordingError

__all__ = ["BLOCK_BYTES", "MAX_LINE_BYTES", "count_line_ends", "text_chunks"]

#: Bytes read at a time; a chunk is at most this plus the rest of the line it cuts.
BLOCK_BYTES = 1 << 20
#: The longest line (bytes, line end excluded) a text file may have.  A recording's row is a few
#: numbers of at most ~25 characters, its header a few column names: 1 MiB is ~40 000 columns, far
#: beyond any instrument, and bounds the text held for one line.
MAX_LINE_BYTES = 1 << 20
_BOM = b"\xef\xbb\xbf"


def _line_ends(raw: bytes) -> int:
    """Line ends in ``raw``, a CR LF counted once."""
    if b"\r" not in raw:  # the usual case: one scan, not three
        return raw.count(b"\n")
    return raw.count(b"\n") + raw.count(b"\r") - raw.count(b"\r\n")


def count_line_ends(fh: BinaryIO, block_bytes: int | None = None) -> int:
    """An upper bound of the line ends from the current position to the end of the file, exact
    but for a CR LF cut between two blocks (counted twice): enough to size an array of rows."""
    total, size = 0, block_bytes or BLOCK_BYTES
    while block := fh.read(size):
        total += _line_ends(block)
    return total


def _decode(raw: bytes, line: int, offset: int, where: str) -> str:
    """``raw`` (whole lines from file line ``line`` and byte ``offset``) as text with LF line ends."""
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        raise RecordingError(f"{where}:{line + _line_ends(raw[:err.start])}: not UTF-8 "
                             f"(byte {offset + err.start})") from err
    return text.replace("\r\n", "\n").replace("\r", "\n") if "\r" in text else text


def _first_line_end(block: bytes) -> int:
    """The index of the first CR or LF in ``block``, or -1."""
    ends = [i for i in (block.find(b"\n"), block.find(b"\r")) if i >= 0]
    return min(ends) if ends else -1


def text_chunks(fh: BinaryIO, where: str, block_bytes: int | None = None,
                max_line_bytes: int | None = None) -> Iterator[tuple[int, str]]:
    """``(number of the chunk's first line, text)`` for the whole file ``fh`` (opened in binary
    mode, at its start): every chunk is whole lines, each ending in LF except perhaps the file's
    last; concatenated they are the file's text.  Invalid UTF-8, or a line longer than
    ``max_line_bytes`` (default :data:`MAX_LINE_BYTES`), is a :class:`RecordingError` naming
    ``where``, the line and the byte.  ``block_bytes`` defaults to :data:`BLOCK_BYTES`."""
    cap = MAX_LINE_BYTES if max_line_bytes is None else max_line_bytes
    # read at most ``cap`` bytes at a time, a line inside one block is shorter than the cap: only
    # the line that spans blocks (``pending``, ``partial`` bytes of it so far) needs measuring
    size = max(1, min(block_bytes or BLOCK_BYTES, cap))
    line, pending, partial = 1, [], 0
    head = fh.read(len(_BOM))
    carry, offset = (b"", len(_BOM)) if head == _BOM else (head, 0)
    while True:
        block = carry + fh.read(max(1, size - len(carry)))
        carry = b""
        if block:
            first = _first_line_end(block)
            if (first if first >= 0 else len(block)) + partial > cap:
                raise RecordingError(f"{where}:{line}: a line longer than {cap} bytes (from byte {offset}); "
                                     "a recording's header and rows are short lines (MAX_LINE_BYTES)")
            # the last line end; a CR at the very end may be the first half of a CR LF: keep it
            cut = max(block.rfind(b"\n"), block.rfind(b"\r", 0, len(block) - 1)) + 1
            if cut == 0:
                pending.append(block)
                partial += len(block)
                continue
            raw = b"".join([*pending, block[:cut]])
            pending, partial = [block[cut:]], len(block) - cut
        else:
            raw = b"".join(pending)
        if raw:
            text = _decode(raw, line, offset, where)
            yield line, text
            line += text.count("\n")
            offset += len(raw)
        if not block:
            return
