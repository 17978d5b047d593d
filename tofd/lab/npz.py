"""Bounds on a dataset .npz (a zip of .npy members) checked before numpy reads it: every member's size in the zip
directory must be what its .npy header's shape and dtype make, and the members read whole stay under a cap. A
deflate bomb or a header that lies is refused from the headers alone (a few kB read), never decompressed.
"""

from __future__ import annotations

import math
import zipfile
from collections.abc import Collection
from typing import IO

import numpy as np

from tofd.errors import DataError

MAX_LOADED_BYTES = 1 << 30
"""Most bytes of .npy members read whole from one dataset (about 5,000 SR3000 frames of range and amplitude)."""


class NpzError(DataError):
    """An .npz whose members are not what their headers say, or larger than tofd reads."""


def read_npy_header(member: IO[bytes]) -> tuple[tuple[int, ...], bool, np.dtype]:
    """(shape, fortran_order, dtype) of the .npy stream at its start (numpy.lib.format's public readers)."""
    version = np.lib.format.read_magic(member)
    read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
    return read(member)


def check_npz(file: IO[bytes], streamed: Collection[str] = (), limit: int | None = None) -> None:
    """NpzError (naming the key) unless every .npy member of the zip in `file` holds exactly its header's
    shape x dtype bytes, has a plain dtype (no pickled objects), and the members other than `streamed` (names
    without .npy, read a frame range at a time) add up to at most `limit` bytes (default MAX_LOADED_BYTES).
    Leaves `file` at its start."""
    limit = MAX_LOADED_BYTES if limit is None else limit
    try:
        zf = zipfile.ZipFile(file)
    except zipfile.BadZipFile:
        raise NpzError("not a dataset .npz (numpy zip archive)") from None
    total = 0
    with zf:
        for info in zf.infolist():
            name = info.filename.removesuffix(".npy")
            with zf.open(info) as member:
                shape, _, dtype = read_npy_header(member)
                start = member.tell()
            if dtype.hasobject:
                raise NpzError(f"key {name!r} holds Python objects: it cannot be read without pickle")
            declared = start + math.prod(shape) * dtype.itemsize
            if declared != info.file_size:
                raise NpzError(f"key {name!r}: its header declares {shape} {dtype} ({declared} bytes), the "
                                 f"archive {info.file_size} bytes")
            if name not in streamed:
                total += info.file_size
            if total > limit:
                raise NpzError(f"key {name!r}: the keys read whole exceed {limit >> 20} MiB decompressed, more "
                                 "than a dataset tofd loads")
    file.seek(0)
