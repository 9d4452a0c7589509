"""The recording interchange format (v1): ``NAME.csv`` samples beside a ``NAME.json`` sidecar.

The contract is ``recording-format.md``.  Reading is strict because the files come from scopes,
DAQ software and spreadsheets: every defect is a :class:`RecordingError` naming the file, and the
line and column where there is one; nothing is dropped, rescaled or guessed.  The numbers go
through numpy in bulk, a chunk of lines at a time into one array, so memory is the samples' float64
size plus a chunk, not a multiple of the text; a pass per line runs only on the error path, to
say where the defect is.  Nothing is read unbounded: a line longer than
:data:`~hystbench.formats.text_chunks.MAX_LINE_BYTES`, a column name longer than
:data:`MAX_COLUMN_NAME_CHARS` or a sidecar larger than
:data:`~hystbench.formats.small_files.MAX_SIDECAR_BYTES` is refused by name.
Writing is lossless (shortest round-trip float text) and replaces files atomically.
"""

from __future__ import annotations

import csv
import io
import itertools
import json
import math
import numbers
import os
import re
import secrets
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO, Callable, Iterable, Iterator, Mapping, Sequence, TextIO

import numpy as np

from ..blocks import CHANNEL_UNITS, BlockFlags, SampleBlock, concatenate
from ..config import rig_names
from ..errors import RecordingError
from ..messages import OperatingPoint
from .outputs import output_folder
from .small_files import MAX_SIDECAR_BYTES, excerpt, finite, read_json, shown
from .text_chunks import count_line_ends, text_chunks

__all__ = ["REQUIRED_KEYS", "TIME_TOL_PERIODS", "MAX_COLUMN_NAME_CHARS", "MAX_SIDECAR_BYTES", "Recording", "read_recording", "write_recording",
           "read_sweep", "write_sweep", "sweep_stem", "sidecar_point", "with_point", "recording_paths", "times_fit"]

#: Sidecar keys every recording must have.
REQUIRED_KEYS = ("rig", "frequency_Hz", "sample_rate_Hz", "current_pp_A")

#: How far (in sample periods) a ``time_s`` value may sit from ``t0 + i / sample_rate_Hz``.
#: The estimators time samples by index and rate, and the channels of a pair share a row, so the
#: column only has to prove that no sample was lost, repeated or shifted (errors of >= 1 period).
#: 1e-3 lets through other tools' time text rounded to 9-10 significant digits (``%.9f`` at
#: 51.2 kS/s errs 2.6e-5 periods), which 1e-6 would refuse (it needs 13+ digits); float64
#: round-off of an hour-long recording is < 1e-7 periods.  Even at 10 kS/s, 1e-3 periods is
#: 0.017 deg at 480 Hz, far under the delays this bench measures.
TIME_TOL_PERIODS = 1e-3

#: The longest column name in a header.  A name is ``<channel>_<unit>`` (``force_N``): 200
#: characters is ten times the longest a tool writes, and keeps a refused name's message short.
MAX_COLUMN_NAME_CHARS = 200

_SUFFIXES = (".csv", ".json")
_ROWS_PER_CHUNK = 65536  # bounds the text held in memory while writing
_TIME_BLOCK = 8192  # samples per step of the time check: its temporaries stay small
_KNOWN = {name.rsplit("_", 1)[0]: name for name in CHANNEL_UNITS}  # 'force' -> 'force_N'
_COLUMN = re.compile(r"(?P<channel>[^\W\d_]\w*)_(?P<unit>(?:[^\W\d_]|[%°])[^\s_,\"]*)")
# The numbers numpy's loadtxt accepts (ASCII, no underscores), to find the bad field on error.
_NUMBER = re.compile(r"\s*[+-]?(?:(?:\d+\.?\d*|\.\d+)(?:e[+-]?\d+)?|inf|infinity|nan)\s*", re.I | re.A)


@dataclass(eq=False)
class Recording:
    """Samples by column name plus the whole sidecar; ``metadata['sample_rate_Hz']`` is filled
    from ``fs_hz`` when absent (both must agree).  Validated on creation and before writing."""

    path: Path | None
    fs_hz: float
    channels: dict[str, np.ndarray]
    metadata: dict
    t0_s: float = 0.0

    def __post_init__(self) -> None:
        self.metadata = dict(self.metadata)
        self.metadata.setdefault("sample_rate_Hz", self.fs_hz)
        self.channels = dict(self.channels)
        self._validate()
        self.fs_hz, self.t0_s = float(self.fs_hz), float(self.t0_s)

    def _validate(self) -> None:
        """Refuse in memory what could not be written or read back."""
        where = str(self.path) if self.path is not None else "recording"
        _check_sidecar(self.metadata, where)
        fs, t0 = self.metadata["sample_rate_Hz"], self.t0_s
        if self.fs_hz != fs:
            raise RecordingError(f"{where}: fs_hz {self.fs_hz!r} differs from metadata sample_rate_Hz {fs!r}")
        if isinstance(t0, bool) or not isinstance(t0, numbers.Real) or not finite(t0):
            raise RecordingError(f"{where}: t0_s must be a finite number, got {t0!r}")
        if not self.channels:
            raise RecordingError(f"{where}: no channels besides time")
        for name, x in self.channels.items():
            if name == "time_s":
                raise RecordingError(f"{where}: 'time_s' is the time column, not a channel; use t0_s")
            _check_column_name(name, f"{where}: channel {name!r}")
            x = self.channels[name] = np.asarray(x, dtype=np.float64)
            if x.ndim != 1 or x.size == 0:
                raise RecordingError(f"{where}: channel {name!r} must be 1-D and non-empty, got {x.shape}")
            if not np.isfinite(x).all():
                i = int(np.argmin(np.isfinite(x)))
                raise RecordingError(f"{where}: channel {name!r} sample {i} is {float(x[i])!r}, not finite")
        if len({x.size for x in self.channels.values()}) > 1:
            sizes = ", ".join(f"{k}={v.size}" for k, v in self.channels.items())
            raise RecordingError(f"{where}: channels differ in length: {sizes}")
        if not times_fit(t0, self.n, fs):
            raise RecordingError(f"{where}: time_s starts at {t0!r} s (t0_s), too far from 0 for float64 to hold "
                                 f"the sample times at {fs:g} Hz within {TIME_TOL_PERIODS:g} of a period "
                                 "(TIME_TOL_PERIODS); start time_s near 0 and keep the clock's offset in the "
                                 "sidecar's start_time_s")

    @property
    def rig(self) -> str:
        return self.metadata["rig"]

    @property
    def frequency_hz(self) -> float:
        """Nominal excitation frequency (sidecar ``frequency_Hz``)."""
        return float(self.metadata["frequency_Hz"])

    @property
    def current_pp_a(self) -> float:
        """Nominal peak-to-peak excitation current (sidecar ``current_pp_A``)."""
        return float(self.metadata["current_pp_A"])

    @property
    def start_time_s(self) -> float | None:
        """When the recording started on the clock its sweep shares (sidecar ``start_time_s``,
        seconds); None when the sidecar does not say (slow effects then show in no ordering)."""
        start = self.metadata.get("start_time_s")
        return None if start is None else float(start)

    @property
    def n(self) -> int:
        """Samples per channel."""
        return len(next(iter(self.channels.values())))

    @property
    def duration_s(self) -> float:
        """``n / fs_hz``: the time the samples cover, one period per sample."""
        return self.n / self.fs_hz

    def time_s(self) -> np.ndarray:
        """The time column, ``t0_s + i / fs_hz``."""
        return self.t0_s + np.arange(self.n) / self.fs_hz

    def to_block(self, first_index: int | None = None) -> SampleBlock:
        """The samples as a pipeline block; by default ``first_index = t0_s * fs_hz``, which must
        then be a whole number of samples (within TIME_TOL_PERIODS) rather than be rounded."""
        if first_index is None:
            first_index = round(self.t0_s * self.fs_hz)
            if abs(self.t0_s * self.fs_hz - first_index) > TIME_TOL_PERIODS:
                raise RecordingError(f"{self.path or 'recording'}: t0_s={self.t0_s!r} is not a whole "
                                     "number of samples; pass first_index")
        return SampleBlock(first_index=int(first_index), fs_hz=self.fs_hz, channels=dict(self.channels))

    @classmethod
    def from_blocks(cls, blocks: Iterable[SampleBlock], metadata: Mapping[str, Any], *,
                    t0_s: float | None = None) -> Recording:
        """Join contiguous blocks; a lost sample cannot be written as uniform time, so it is refused.
        A clipped block sets ``clipped: true`` in the metadata, since the flag has no column.
        ``t0_s``: the first sample's time (None: its index over the rate, the source's clock)."""
        blocks = list(blocks)
        if not blocks:
            raise RecordingError("from_blocks: no blocks")
        first = blocks[0]
        for k, b in enumerate(blocks[1:], start=1):
            if b.fs_hz != first.fs_hz or set(b.channels) != set(first.channels):
                raise RecordingError(f"from_blocks: block {k} has {b.fs_hz} Hz, {sorted(b.channels)}; "
                                     f"block 0 {first.fs_hz} Hz, {sorted(first.channels)}")
            if b.flags & (BlockFlags.GAP | BlockFlags.OVERRUN):
                raise RecordingError(f"from_blocks: samples were lost before block {k} ({b.flags!r})")
        try:
            block = concatenate(blocks)
        except ValueError as err:
            raise RecordingError(f"from_blocks: {err}") from err
        meta = {**metadata, **({"clipped": True} if block.flags & BlockFlags.CLIP else {})}
        return cls(path=None, fs_hz=block.fs_hz, channels=dict(block.channels), metadata=meta,
                   t0_s=block.first_index / block.fs_hz if t0_s is None else t0_s)


def times_fit(t0_s: float, n: int, fs_hz: float) -> bool:
    """Whether float64 holds the times of ``n`` samples at ``fs_hz`` from ``t0_s`` within
    TIME_TOL_PERIODS of a period (an eighth of it): a clock that ran for months does not."""
    return bool(np.spacing(abs(t0_s) + n / fs_hz) <= TIME_TOL_PERIODS / fs_hz / 8)


def recording_paths(path: str | Path) -> tuple[Path, Path, Path]:
    """(stem, csv, json).  Only a .csv/.json suffix is removed: '..._1.4App' keeps its '.4App'."""
    p = Path(path)
    stem = p.with_suffix("") if p.suffix in _SUFFIXES else p
    return stem, stem.with_name(stem.name + ".csv"), stem.with_name(stem.name + ".json")


def _check_column_name(name: str, where: str) -> None:
    m = _COLUMN.fullmatch(name)
    if m is None:
        raise RecordingError(f"{where}: {name!r} is not <channel>_<unit> (e.g. force_N); name its unit")
    known = _KNOWN.get(m["channel"])
    if known is not None and known != name:
        raise RecordingError(f"{where}: {name!r}: the format defines this channel as {known!r} "
                             f"({CHANNEL_UNITS[known]}); convert the values, nothing is rescaled here")


def _check_sidecar(meta: Any, where: str) -> None:
    if not isinstance(meta, dict):
        raise RecordingError(f"{where}: the sidecar must be a JSON object, got {type(meta).__name__}")
    for key in REQUIRED_KEYS:
        if key not in meta:
            raise RecordingError(f"{where}: missing key {key!r} (required: {', '.join(REQUIRED_KEYS)})")
    if not isinstance(meta["rig"], str):
        raise RecordingError(f"{where}: key 'rig' must be a string, got {meta['rig']!r}")
    if meta["rig"] not in rig_names():
        raise RecordingError(f"{where}: unknown rig {meta['rig']!r}; known: {', '.join(rig_names())}")
    for key in REQUIRED_KEYS[1:]:
        v, low = meta[key], ">= 0" if key == "current_pp_A" else "> 0"
        if isinstance(v, bool) or not isinstance(v, numbers.Real):
            raise RecordingError(f"{where}: key {key!r} must be a number, got {v!r}")
        if not finite(v) or v < 0 or (v == 0 and low == "> 0"):
            raise RecordingError(f"{where}: key {key!r} must be finite and {low}, got {shown(v)}")
    f, fs = meta["frequency_Hz"], meta["sample_rate_Hz"]
    if f >= fs / 2:
        raise RecordingError(f"{where}: frequency_Hz {f!r} is not below half of sample_rate_Hz {fs!r}")
    start = meta.get("start_time_s")  # optional: the recording's start on the sweep's clock
    if "start_time_s" in meta and (isinstance(start, bool) or not isinstance(start, numbers.Real)
                                   or not finite(start)):
        raise RecordingError(f"{where}: key 'start_time_s' must be a finite number of seconds, got {shown(start)}")


def _read_sidecar(path: Path) -> dict:
    meta = read_json(path)
    _check_sidecar(meta, str(path))
    return meta


def _check_name_lengths(names: list[str], where: str) -> None:
    for j, name in enumerate(names, start=1):
        if len(name.strip()) > MAX_COLUMN_NAME_CHARS:
            raise RecordingError(f"{where}:1: column {j}: a name of {len(name.strip())} characters (at most "
                                 f"{MAX_COLUMN_NAME_CHARS}), starting {name.strip()[:40]!r}; a column is named "
                                 "<channel>_<unit> (e.g. force_N)")


def _parse_header(line: str, where: str) -> list[str]:
    if not line.strip():
        raise RecordingError(f"{where}:1: empty header line; expected 'time_s,<channel>_<unit>,...'")
    _check_name_lengths(line.split(","), where)  # before csv, whose field limit raises its own error
    try:
        names = [n.strip() for n in next(csv.reader([line]))]
    except csv.Error as err:
        raise RecordingError(f"{where}:1: the header is not a CSV line of column names ({err})") from err
    _check_name_lengths(names, where)  # a quoted name may hold commas
    for j, name in enumerate(names):
        if not name:
            raise RecordingError(f"{where}:1: column {j + 1} has no name")
        if name in names[:j]:
            raise RecordingError(f"{where}:1: column {j + 1} {name!r} repeats column {names.index(name) + 1}")
    if "time_s" not in names:
        other = [n for n in names if n.startswith("time")]
        hint = f" (found {', '.join(other)}; time must be in seconds)" if other else ""
        raise RecordingError(f"{where}:1: missing the time_s column{hint}")
    if names[0] != "time_s":
        raise RecordingError(f"{where}:1: time_s must be column 1, found in column {names.index('time_s') + 1}")
    if len(names) == 1:
        raise RecordingError(f"{where}:1: no channel columns besides time_s")
    for j, name in enumerate(names[1:], start=2):
        _check_column_name(name, f"{where}:1: column {j}")
    return names


def _locate_bad_line(body: str, names: list[str], where: str, first_line: int) -> RecordingError | None:
    """The error path: walk the lines to name the first one loadtxt refused or skipped."""
    for lineno, line in enumerate(body.split("\n"), start=first_line):
        if not line.strip():
            return RecordingError(f"{where}:{lineno}: empty line between samples")
        fields = line.split(",")
        if len(fields) != len(names):
            return RecordingError(f"{where}:{lineno}: {len(fields)} fields, the header has {len(names)}")
        for j, f in enumerate(fields):
            if not _NUMBER.fullmatch(f):
                what = "empty field" if not f.strip() else f"not a number: {excerpt(f.strip())}"
                return RecordingError(f"{where}:{lineno}: column {j + 1} ({names[j]}): {what}")
    return None


def _parse_rows(body: str, names: list[str], where: str, first_line: int) -> np.ndarray:
    """The (rows, columns) float64 array of ``body``, whole lines from file line ``first_line``
    on, checked for shape and finiteness."""
    rows = body.count("\n") + 1
    try:
        data = np.loadtxt(io.StringIO(body), delimiter=",", comments=None, ndmin=2, dtype=np.float64)
    except ValueError as err:
        raise (_locate_bad_line(body, names, where, first_line)
               or RecordingError(f"{where}:{first_line}: cannot read the samples from here on: {err}")) from err
    if data.shape != (rows, len(names)):  # loadtxt skips empty lines; a constant extra field passes
        raise (_locate_bad_line(body, names, where, first_line)
               or RecordingError(f"{where}:{first_line}: read {data.shape} samples, expected ({rows}, {len(names)})"))
    bad = ~np.isfinite(data)
    if bad.any():
        r, c = divmod(int(np.argmax(bad)), data.shape[1])
        field = body.split("\n", r + 1)[r].split(",")[c].strip()
        raise RecordingError(f"{where}:{first_line + r}: column {c + 1} ({names[c]}): "
                             f"{excerpt(field)} is not a finite number")
    return data


def _read_header(chunks: Iterator[tuple[int, str]], where: str) -> tuple[list[str], str]:
    """The header's names and the rest of the first chunk (from line 2 on)."""
    first = next(chunks, (1, ""))[1]
    header, _, rest = first.partition("\n")
    if not header.strip() and not rest.strip() and not any(text.strip() for _, text in chunks):
        raise RecordingError(f"{where}: empty file; expected a header line 'time_s,...' and samples")
    return _parse_header(header, where), rest


def _parse_samples(fh: BinaryIO, where: str) -> tuple[list[str], np.ndarray]:
    """Header names and the (columns, rows) float64 array of the CSV ``fh``, read a chunk of
    lines at a time into one array sized by a first pass that counts the lines: the memory is
    that array plus a chunk, not a multiple of the text.  The first defect in the file is named."""
    lines = count_line_ends(fh) + 1
    size = fh.tell()
    fh.seek(0)
    chunks = text_chunks(fh, where)
    names, rest = _read_header(chunks, where)
    # A row of k fields takes >= 2k bytes (a digit and a comma or line end each), so the rows the
    # file can hold bound the array too: many columns over many short lines must not size it.
    capacity = min(lines, (size + 1) // (2 * len(names)) + 1)
    out = np.empty((len(names), capacity), dtype=np.float64)
    n = 0
    blank: int | None = None  # the first of the whitespace-only lines after the last sample so far
    for first_line, text in itertools.chain([(2, rest)], chunks):
        body = text.rstrip()  # whitespace-only lines at the end of the file hold no sample
        if not body:
            blank = first_line if blank is None and text else blank
            continue
        if blank is not None:
            raise RecordingError(f"{where}:{blank}: empty line between samples")
        data = _parse_rows(body, names, where, first_line)
        if n + data.shape[0] > capacity:
            raise RecordingError(f"{where}: the file grew while being read")
        out[:, n:n + data.shape[0]] = data.T
        n += data.shape[0]
        end = text.find("\n", len(body)) + 1  # just after the line of the last sample
        blank = first_line + data.shape[0] if 0 < end < len(text) else None
    if n == 0:
        raise RecordingError(f"{where}: header only, no samples")
    return names, out[:, :n]


def _max_time_deviation(t: np.ndarray, period: float) -> float:
    """``max |t[i] - (t[0] + i period)|``, a block at a time: no temporary the size of the column."""
    worst = 0.0
    for start in range(0, t.size, _TIME_BLOCK):
        i = np.arange(start, min(start + _TIME_BLOCK, t.size))
        worst = max(worst, float(np.max(np.abs(t[i[0]:i[-1] + 1] - (t[0] + i * period)))))
    return worst


def _check_time(t: np.ndarray, fs_hz: float, where: str, sidecar: str) -> None:
    """time_s must sit on t[0] + i / fs_hz within TIME_TOL_PERIODS; say which line leaves it, and why."""
    period = 1.0 / fs_hz
    tol = TIME_TOL_PERIODS * period
    if t.size < 2 or _max_time_deviation(t, period) <= tol:
        return
    dev = t - (t[0] + np.arange(t.size) * period)  # the error path: whole-column temporaries are fine
    steps = np.diff(t)
    step = float(np.median(steps))
    # Uniformity is judged on the column's own step when it is the longer one: with a sidecar rate
    # far off (1e308 Hz), a tolerance of its period falls below the float resolution of time_s and
    # every step would look non-uniform; the rate is then what is wrong, and the message says so.
    step_tol = TIME_TOL_PERIODS * max(period, step) if step > 0 else tol
    off = (steps <= 0) | (np.abs(steps - step) > 2 * step_tol)  # one rounded value moves two steps
    if off.any():
        i = int(np.argmax(off))
        what = "does not increase" if steps[i] <= 0 else "is non-uniform"
        raise RecordingError(f"{where}:{i + 3}: time_s {what}: {float(t[i + 1])!r} s follows "
                             f"{float(t[i])!r} s, a step of {steps[i]:.9g} s where most are {step:.9g} s "
                             f"(tolerance {TIME_TOL_PERIODS:g} periods)")
    i = int(np.argmax(np.abs(dev) > tol))
    rate = (t.size - 1) / (t[-1] - t[0])
    raise RecordingError(f"{where}:{i + 2}: time_s is sampled at {rate:.9g} Hz but {sidecar} says "
                         f"sample_rate_Hz {fs_hz:.9g}; here time_s is {dev[i] / period:+.3g} periods of "
                         f"1/sample_rate_Hz off (steps of {step:.9g} s, not {period:.9g} s)")


def read_recording(path: str | Path) -> Recording:
    """Read ``NAME.csv`` + ``NAME.json``; ``path`` is the stem or either file."""
    stem, csv_path, json_path = recording_paths(path)
    if not json_path.is_file():
        if not csv_path.is_file():
            raise RecordingError(f"{stem}: no recording (neither {csv_path.name} nor {json_path.name})")
        raise RecordingError(f"{json_path}: missing sidecar for {csv_path.name}")
    meta = _read_sidecar(json_path)
    if not csv_path.is_file():
        raise RecordingError(f"{csv_path}: missing samples for sidecar {json_path.name}")
    try:
        with csv_path.open("rb") as fh:
            names, cols = _parse_samples(fh, str(csv_path))
    except OSError as err:
        raise RecordingError(f"{csv_path}: cannot read: {err.strerror}") from err
    fs = float(meta["sample_rate_Hz"])
    _check_time(cols[0], fs, str(csv_path), json_path.name)
    # each channel is a contiguous row of ``cols``: views, no copy
    return Recording(path=stem, fs_hz=fs, channels=dict(zip(names[1:], cols[1:])),
                     metadata=meta, t0_s=float(cols[0, 0]))


def _write_csv(fh: TextIO, rec: Recording) -> None:
    fh.write(",".join(["time_s", *rec.channels]) + "\n")
    cols = [rec.time_s(), *rec.channels.values()]
    for start in range(0, rec.n, _ROWS_PER_CHUNK):
        # repr is the shortest text that reads back to the same float64: lossless and readable
        text = [map(repr, c[start:start + _ROWS_PER_CHUNK].tolist()) for c in cols]
        fh.write("\n".join(map(",".join, zip(*text))) + "\n")


def _write_temp(dest: Path, write: Callable[[TextIO], Any]) -> Path:
    """A fully written, fsynced hidden temporary beside ``dest`` (same file system, so the rename
    is atomic); removed again if writing fails."""
    tmp = dest.with_name(f".{dest.name}.{secrets.token_hex(4)}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)  # the umask applies, as for open()
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="\n") as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return tmp


def _refuse_existing(paths: Iterable[Path]) -> None:
    for p in paths:
        if p.exists():
            raise RecordingError(f"{p}: already exists; give --overwrite (overwrite=True from Python) to replace it")


def write_recording(rec: Recording, stem: str | Path, *, overwrite: bool = False) -> tuple[Path, Path]:
    """Write ``STEM.csv`` and ``STEM.json``; returns their paths and sets ``rec.path``.

    Each file is written to a temporary beside it and renamed over the target, so a crash leaves
    the old file whole; both temporaries are complete before either rename.  An existing
    recording is replaced only with ``overwrite=True``.
    """
    stem, csv_path, json_path = recording_paths(stem)
    rec._validate()
    if not overwrite:
        _refuse_existing([csv_path, json_path])
    try:
        sidecar = json.dumps(rec.metadata, indent=2, ensure_ascii=False, allow_nan=False) + "\n"
    except (TypeError, ValueError) as err:
        raise RecordingError(f"{json_path}: metadata cannot be written as JSON: {err}") from err
    temps: list[Path] = []
    try:
        temps.append(_write_temp(csv_path, lambda fh: _write_csv(fh, rec)))
        temps.append(_write_temp(json_path, lambda fh: fh.write(sidecar)))
        os.replace(temps[0], csv_path)
        os.replace(temps[1], json_path)
    except OSError as err:
        # the error's own text names the hidden temporary, which the user never sees
        raise RecordingError(f"{stem}: cannot write the recording: {err.strerror or type(err).__name__}") from err
    finally:
        for tmp in temps:
            tmp.unlink(missing_ok=True)
    rec.path = stem
    return csv_path, json_path


def sidecar_point(metadata: Mapping[str, Any]) -> OperatingPoint:
    """The nominal operating point a sidecar names: the one place the interchange spellings
    (``frequency_Hz``, ``current_pp_A``, ``offset_A``) meet the live path's (:mod:`hystbench.messages`);
    a key the sidecar lacks is NaN (offset: 0)."""
    get = metadata.get
    return OperatingPoint(float(get("frequency_Hz", math.nan)), float(get("current_pp_A", math.nan)),
                          float(get("offset_A", 0.0)))


def with_point(metadata: Mapping[str, Any], point: OperatingPoint) -> dict[str, Any]:
    """The sidecar ``metadata`` for samples played at ``point`` (its NaN fields leave the sidecar's
    value): output off says ``output_on: false`` and 0 A-pp (the generator's setting is kept as
    ``generator_current_pp_A``), settling ``settling: true``."""
    meta = dict(metadata)
    f0, gen = meta.get("frequency_Hz"), meta.get("generator_frequency_Hz")
    if isinstance(f0, (int, float)) and isinstance(gen, (int, float)) and f0 > 0 \
            and not math.isnan(point.frequency_hz) and point.frequency_hz != f0:
        # the generator's clock error is its own, at any frequency: a log that started at 320 Hz and
        # recorded at 1000 Hz said generator_frequency_Hz 320.008 beside frequency_Hz 1000
        meta["generator_frequency_Hz"] = float(point.frequency_hz) * gen / f0
    for value, key in ((point.frequency_hz, "frequency_Hz"), (point.current_pp_a, "current_pp_A"),
                       (point.offset_a, "offset_A")):
        if not math.isnan(value):
            meta[key] = float(value)
    if not point.output_on:
        meta["generator_current_pp_A"] = meta.get("current_pp_A", 0.0)
        meta["current_pp_A"] = 0.0
        meta["output_on"] = False
    if point.settling:
        meta["settling"] = True
    return meta


def sweep_stem(rec: Recording) -> str:
    """The file stem of a recording in a sweep folder, e.g. ``ecore_pm_320Hz_1.4App``."""
    return f"{rec.rig}_{rec.frequency_hz:g}Hz_{rec.current_pp_a:g}App"


def read_sweep(folder: str | Path, *, one_rig: bool = False) -> list[Recording]:
    """Every recording in ``folder``, sorted by (rig, frequency_Hz, current_pp_A, path).

    A bench day's folder may hold the recordings of several rigs, told apart by each sidecar's
    ``rig`` (``recording-format.md``); they are all returned, each rig's together.  A caller that
    takes one actuator's sweep passes ``one_rig=True``: a folder of several rigs is then refused,
    naming the folder and its rigs."""
    folder = Path(folder)
    if not folder.is_dir():
        raise RecordingError(f"{folder}: not a folder")
    files = [p for p in folder.iterdir() if p.is_file() and not p.name.startswith(".")]
    odd = sorted(p.name for p in files if p.suffix.lower() in _SUFFIXES and p.suffix not in _SUFFIXES)
    if odd:
        raise RecordingError(f"{folder}: suffixes must be .csv and .json in lower case: {', '.join(odd)}")
    stems = {p.with_suffix("") for p in files if p.suffix == ".csv"}
    orphans = sorted(p.name for p in files if p.suffix == ".json" and p.with_suffix("") not in stems)
    if orphans:
        raise RecordingError(f"{folder}: sidecars without a .csv: {', '.join(orphans)}")
    if not stems:
        raise RecordingError(f"{folder}: no recordings (NAME.csv + NAME.json) in this folder")
    recs = sorted((read_recording(s) for s in sorted(stems)),
                  key=lambda r: (r.rig, r.frequency_hz, r.current_pp_a, str(r.path)))
    if one_rig:
        counts = {rig: sum(r.rig == rig for r in recs) for rig in dict.fromkeys(r.rig for r in recs)}
        if len(counts) > 1:
            rigs = ", ".join(f"{rig}: {n} recording{'s' * (n != 1)}" for rig, n in counts.items())
            raise RecordingError(f"{folder}: recordings of several rigs ({rigs}); this takes one rig's sweep: "
                                 "move the recordings of the rig to use (sidecar 'rig') into a folder of their own")
    return recs


def write_sweep(recordings: Iterable[Recording], folder: str | Path, *, overwrite: bool = False,
                names: Sequence[str] | None = None) -> list[Path]:
    """Write each recording as ``folder/<sweep_stem>`` (or ``folder/<names[k]>``); returns the stems.
    Name clashes and (unless ``overwrite``) existing files are refused before anything is written;
    the recordings are written into a hidden folder beside ``folder`` and moved in when all are
    there, so a failure half-way (a full disk, Ctrl-C) leaves the folder as it was."""
    recs, folder = list(recordings), Path(folder)
    if not recs:
        raise RecordingError(f"{folder}: no recordings to write")
    stems = [folder / n for n in (names if names is not None else [sweep_stem(r) for r in recs])]
    for k, s in enumerate(stems):
        if s in stems[:k]:
            raise RecordingError(f"{s}: recordings {stems.index(s)} and {k} would both be written here")
    if not overwrite:
        _refuse_existing(p for s in stems for p in recording_paths(s)[1:])
    with output_folder(folder, overwrite=True) as stage:  # what exists was refused above, unless overwrite
        for r, s in zip(recs, stems):
            write_recording(r, stage.path / s.name, overwrite=True)
    for r, s in zip(recs, stems):
        r.path = s
    return stems
