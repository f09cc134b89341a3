"""A safe reader for `.npz` files that come from someone else (uploads, `--demos`, checkpoints).

`np.load` trusts the archive: it decompresses whatever a member holds, so a few MB can
become GBs (a "zip bomb"), and a damaged member surfaces as zlib.error, EOFError or
AttributeError. Here every member's `.npy` header (shape, dtype) is read first, sizes are
checked against limits the caller sets, only the requested keys are ever decompressed,
and the data is read through a stream bounded by the header. Nothing is ever unpickled.
Every problem becomes one `NpzError` naming the file and the member.

    headers = npz_headers("demos.npz", ["obs"])     # shapes and dtypes, no data read
    arrays = read_npz("demos.npz", ["obs"], max_array_bytes=2**28, max_total_bytes=2**29)
"""
from __future__ import annotations

import io
import lzma
import math
import struct
import threading
import zipfile
import zlib
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
from numpy.lib import format as npy

CHUNK = 1 << 20  # data is copied in 1 MiB pieces: memory stays at the array's own size

# What zipfile, zlib, lzma and numpy raise on damaged or hostile input.
_READ_ERRORS = (zipfile.BadZipFile, zlib.error, lzma.LZMAError, EOFError, OSError, ValueError, KeyError,
                NotImplementedError, RuntimeError, struct.error, OverflowError)


class NpzError(ValueError):
    """An .npz file (or one of its members) that cannot be read safely; the message says why."""


@dataclass(frozen=True)
class ArrayHeader:
    """One member's .npy header plus the zip's sizes for it. Reading it reads no array data."""

    member: str              # name inside the zip, e.g. "obs.npy"
    shape: tuple[int, ...]
    dtype: np.dtype
    fortran_order: bool
    compressed_size: int     # bytes the member takes in the zip
    file_size: int           # bytes the zip says the member holds once decompressed (header + data)
    data_offset: int         # length of the .npy header, where the data starts

    @property
    def ndim(self) -> int:
        return len(self.shape)

    @property
    def nbytes(self) -> int:
        """Data bytes the header declares; Python ints, so 10**12 rows cannot overflow."""
        return math.prod(self.shape) * self.dtype.itemsize


def _label(source) -> str:
    return "the archive" if isinstance(source, (bytes, bytearray, memoryview)) else str(source)


def _open_zip(source) -> zipfile.ZipFile:
    return zipfile.ZipFile(io.BytesIO(source) if isinstance(source, (bytes, bytearray, memoryview)) else source)


def _key(name: str) -> str:
    return name[:-4] if name.endswith(".npy") else name


def _members(zf: zipfile.ZipFile, keys, label: str) -> dict[str, zipfile.ZipInfo]:
    """key -> zip member for the requested keys (all if None); a key stored twice is refused:
    which copy would be read is up to the zip library, and the two may differ."""
    if isinstance(keys, str):
        keys = (keys,)
    wanted = None if keys is None else {_key(k) for k in keys}
    found: dict[str, zipfile.ZipInfo] = {}
    for info in zf.infolist():
        key = _key(info.filename)
        if wanted is not None and key not in wanted:
            continue  # never opened, never decompressed
        if key in found:
            raise NpzError(f"{label}: holds '{key}' twice ({found[key].filename}, {info.filename}); "
                           f"refusing to guess which one is meant")
        found[key] = info
    return found


# numpy parses a .npy header with ast.literal_eval, and CPython 3.11 keeps the AST builder's recursion count per
# interpreter, not per thread (gh-106905): two threads parsing at once (students opening rollout videos, whose
# experts load from .npz) can fail with "SystemError: AST constructor recursion depth mismatch". Every .npy
# header this package parses, here and in ifo.io.load_state_dict, is parsed under this lock.
NPY_HEADER_LOCK = threading.Lock()


def _read_header(f, info: zipfile.ZipInfo, label: str) -> ArrayHeader:
    """Parse the .npy header at the start of member stream `f`, leaving `f` at the data."""
    where = f"{label}: member '{info.filename}'"
    try:
        version = npy.read_magic(f)
    except ValueError:
        raise NpzError(f"{where} is not a .npy array (no .npy magic at its start)") from None
    if version not in ((1, 0), (2, 0)):  # 3.0 only exists for structured dtypes with non-latin-1 names: refused anyway
        raise NpzError(f"{where} uses .npy format version {version[0]}.{version[1]}, which is not accepted")
    try:
        read = npy.read_array_header_1_0 if version == (1, 0) else npy.read_array_header_2_0
        with NPY_HEADER_LOCK:
            shape, fortran_order, dtype = read(f)  # a literal dict of at most 10,000 characters, parsed without eval
    except ValueError as exc:
        raise NpzError(f"{where} has an invalid .npy header ({exc})") from None
    if any(d < 0 for d in shape):
        raise NpzError(f"{where} declares the impossible shape {shape}")
    return ArrayHeader(info.filename, tuple(shape), dtype, fortran_order, info.compress_size, info.file_size, f.tell())


@contextmanager
def _guard(label: str, member: str = ""):
    """Turn what zipfile/zlib/numpy raise on a damaged file into one NpzError naming the file (and member)."""
    try:
        yield
    except NpzError:
        raise
    except FileNotFoundError:
        raise NpzError(f"{label}: no such file") from None
    except zipfile.BadZipFile as exc:
        if member:
            raise NpzError(f"{label}: member '{member}' is damaged ({exc})") from None
        raise NpzError(f"{label}: not an .npz archive, or a damaged one ({exc})") from None
    except _READ_ERRORS as exc:
        where = f"{label}: member '{member}'" if member else label
        raise NpzError(f"{where} is damaged or unreadable ({type(exc).__name__}: {exc})") from None


def _headers(zf: zipfile.ZipFile, members: dict[str, zipfile.ZipInfo], label: str) -> dict[str, ArrayHeader]:
    out = {}
    for key, info in members.items():
        with _guard(label, info.filename), zf.open(info) as f:  # decompresses the header only: a few hundred bytes
            out[key] = _read_header(f, info, label)
    return out


def npz_keys(source) -> list[str]:
    """The names of all arrays in the archive (member names without '.npy'), from its directory only."""
    label = _label(source)
    with _guard(label), _open_zip(source) as zf:
        return [_key(n) for n in zf.namelist()]


def npz_headers(source, keys=None) -> dict[str, ArrayHeader]:
    """key -> ArrayHeader for `keys` present in the archive (all members if None), reading no array data.
    Requested keys the archive lacks are simply absent: the caller knows which ones it needs."""
    label = _label(source)
    with _guard(label), _open_zip(source) as zf:
        return _headers(zf, _members(zf, keys, label), label)


def _check_header(key: str, h: ArrayHeader, label: str, max_array_bytes: int) -> None:
    where = f"{label}: member '{h.member}'"
    if h.dtype.hasobject:
        raise NpzError(f"{where} holds Python objects (a pickled array); only plain arrays are read, "
                       f"and pickles are never loaded")
    if h.dtype.kind == "V":  # structured/void data: not numbers, and a way to smuggle objects in
        raise NpzError(f"{where} has the structured dtype {h.dtype}; only plain arrays are read")
    if h.nbytes > max_array_bytes:
        raise NpzError(f"{where}: '{key}' of shape {h.shape} and dtype {h.dtype} would take "
                       f"{h.nbytes / 2**20:,.1f} MiB once decompressed; "
                       f"the limit is {max_array_bytes / 2**20:,.1f} MiB")
    # zip and header must agree before anything is decompressed (a bomb hides its data behind a small header)
    if h.file_size != h.data_offset + h.nbytes:
        raise NpzError(f"{where} holds {h.file_size - h.data_offset:,} data bytes but its .npy header declares "
                       f"{h.nbytes:,} (shape {h.shape}, dtype {h.dtype})")


def _read_data(f, h: ArrayHeader, label: str) -> np.ndarray:
    """Exactly h.nbytes bytes from `f` (already past the header) into a new array; more or fewer is an error.
    The zip's own size fields are not trusted: the stream is bounded by the .npy header."""
    where = f"{label}: member '{h.member}'"
    count = math.prod(h.shape)
    flat = np.empty(count, dtype=h.dtype)
    if h.nbytes:
        raw = flat.view(np.uint8)
        pos = 0
        while pos < h.nbytes:
            chunk = f.read(min(CHUNK, h.nbytes - pos))
            if not chunk:
                raise NpzError(f"{where} ends after {pos:,} of the {h.nbytes:,} data bytes its header declares")
            raw[pos:pos + len(chunk)] = np.frombuffer(chunk, dtype=np.uint8)
            pos += len(chunk)
    if f.read(1):
        raise NpzError(f"{where} holds more data than the {h.nbytes:,} bytes its header declares")
    # .npy stores Fortran-ordered arrays with the axes reversed, as numpy.lib.format.read_array does
    return flat.reshape(h.shape[::-1]).transpose() if h.fortran_order else flat.reshape(h.shape)


def read_npz(source, keys=None, *, max_array_bytes: int, max_total_bytes: int) -> dict[str, np.ndarray]:
    """key -> array for `keys` present in the archive (all if None); other members are never decompressed.

    `source` is a path or the file's bytes. Headers are checked first: no object, void or structured
    dtypes, each array at most `max_array_bytes` and all together at most `max_total_bytes` once
    decompressed. Raises NpzError (a ValueError) naming the file and the member for any problem."""
    label = _label(source)
    with _guard(label), _open_zip(source) as zf:
        members = _members(zf, keys, label)
        headers = _headers(zf, members, label)
        for key, h in headers.items():
            _check_header(key, h, label, max_array_bytes)
        total = sum(h.nbytes for h in headers.values())
        if total > max_total_bytes:
            raise NpzError(f"{label}: the arrays {sorted(headers)} would take {total / 2**20:,.1f} MiB once "
                           f"decompressed; the limit is {max_total_bytes / 2**20:,.1f} MiB")
        out = {}
        for key, info in members.items():
            with _guard(label, info.filename), zf.open(info) as f:
                h = _read_header(f, info, label)
                if h != headers[key]:  # changed between the two reads (the file was rewritten meanwhile)
                    raise NpzError(f"{label}: member '{info.filename}' changed while it was being read")
                out[key] = _read_data(f, h, label)
    return out
