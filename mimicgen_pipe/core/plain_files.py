"""Files a user brings in (source demos, a robomimic dataset to train on, their JSON
sidecars) are plain: a regular file, and an HDF5 file whose data all lie inside it. HDF5
can store a dataset's bytes in another file (external storage), link to an object of
another file (external links) or assemble a dataset from other files' datasets (virtual
datasets); a reader that follows them reads whatever file they name (/etc/passwd read as
actions). Every reader of such a file opens it here, and is refused with one InputError
line naming the file and the object before any data is read."""

from __future__ import annotations

import os
import re
import stat
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from mimicgen_pipe.core.errors import InputError

if TYPE_CHECKING:
    import h5py
    from h5py import h5d, h5l, h5o

JSON_LIMIT = 16 * 2**20  # bytes of a JSON sidecar: ManiSkill writes ~200 an episode
# bytes one dataset may declare: far above any demo file's, far below what a forged shape
# (10**12 rows) asks for; each reader also bounds its arrays' rows (MAX_STEPS)
DATASET_LIMIT = 2**36
MAX_STEPS = 100_000  # steps of one demo (83 min at 20 Hz)
MAX_WIDTH = 10_000  # values of one action or flat state
SEED_RANGE = (0, 2**31 - 1)  # a file's reset seed; -1 means the file gives none
# HDF5's own filters and h5py's lzf: any other id would make HDF5 search for a plugin
FILTERS = {1: "deflate", 2: "shuffle", 3: "fletcher32", 4: "szip", 5: "nbit",
           6: "scaleoffset", 32000: "lzf"}  # fmt: skip


def regular_file(path: str | os.PathLike, what: str, limit: int | None = None) -> int:
    """The size [bytes] of ``path``, a regular file (symbolic links followed): InputError
    naming it when it is missing, or a folder, FIFO, device or socket (which would block a
    reader or never end), or larger than ``limit``."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise InputError(f"{path}: {what} not found") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read the {what} ({exc.strerror or exc})") from None
    if not stat.S_ISREG(st.st_mode):
        raise InputError(
            f"{path}: cannot read the {what} (it is {_kind(st.st_mode)}, not a regular file)"
        )
    if limit is not None and st.st_size > limit:
        raise InputError(f"{path}: {st.st_size} bytes, more than the {limit} a {what} may have")
    return st.st_size


def _kind(mode: int) -> str:
    kinds = ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a device"),
             (stat.S_ISBLK, "a device"), (stat.S_ISSOCK, "a socket"))  # fmt: skip
    return next((name for test, name in kinds if test(mode)), "not a file")


def open_hdf5(path: str | os.PathLike, what: str) -> h5py.File:
    """``path`` opened read-only, a regular file that is HDF5 and plain (:func:`check_plain`);
    InputError naming the file otherwise. The caller closes it."""
    import h5py  # here: the YAML readers use regular_file without loading HDF5

    regular_file(path, what)
    try:
        f = h5py.File(path, "r")
    except OSError as exc:  # not HDF5 at all, or cut short (h5py's message says which)
        raise InputError(f"{path}: not a readable HDF5 {what} ({exc})") from exc
    try:
        check_plain(f, Path(path))
    except BaseException:
        f.close()
        raise
    return f


def check_plain(f: h5py.File, path: Path) -> None:
    """InputError naming ``path`` and the object unless every link of ``f`` is a hard link
    and every dataset keeps its data in ``f``: no soft or external link, no external
    storage, no virtual dataset over another file, no filter but HDF5's own, no
    big-endian data and no declared size over DATASET_LIMIT. Links are read, never
    followed; HDF5's own visitors walk the file (h5py's per-name lookups take seconds on an
    export of a thousand demos)."""
    from h5py import h5d, h5l, h5o

    def link(name: bytes, info: h5l.LinkInfo) -> str | None:
        # a visitor stops at the first value it returns
        return None if info.type == h5l.TYPE_HARD else name.decode(errors="replace")

    if (name := f.id.links.visit(link, info=True)) is not None:
        raise InputError(
            f"{path}: {name} is {_link_text(f.get(name, getlink=True))}; expected the data in "
            "the file itself (no links to other objects or files)"
        )

    def dataset(name: bytes, info: h5o.ObjInfo) -> str | None:
        if info.type != h5o.TYPE_DATASET:
            return None
        return _dataset_problem(h5d.open(f.id, name), f"{path}: {name.decode(errors='replace')}")

    if (problem := h5o.visit(f.id, dataset, info=True)) is not None:
        raise InputError(problem)


def _link_text(link: object) -> str:
    import h5py

    if isinstance(link, h5py.ExternalLink):
        return f"an external link to {link.filename}:{link.path}"
    if isinstance(link, h5py.SoftLink):
        return f"a soft link to {link.path}"
    return "a user-defined link"


def _dataset_problem(d: h5d.DatasetID, where: str) -> str | None:
    """What :func:`check_plain` refuses in one dataset (None: nothing), from its metadata."""
    from h5py import h5d

    plist = d.get_create_plist()
    if plist.get_external_count():
        file = plist.get_external(0)[0].decode(errors="replace")
        return f"{where} stores its data in another file ({file}); expected it inside"
    if plist.get_layout() == h5d.VIRTUAL:
        for i in range(plist.get_virtual_count()):
            if (file := plist.get_virtual_filename(i)) != ".":  # ".": this file
                return f"{where} is a virtual dataset over {file}; expected its data inside"
    for i in range(plist.get_nfilters()):
        if (code := plist.get_filter(i)[0]) not in FILTERS:
            known = ", ".join(FILTERS.values())
            return f"{where} is compressed by filter {code}; expected one of HDF5's own ({known})"
    if d.dtype.byteorder == ">":
        return f"{where} has big-endian dtype {d.dtype.str}; expected little-endian"
    declared = int(np.prod(d.shape, dtype=object)) * d.dtype.itemsize
    if declared > DATASET_LIMIT:
        return (
            f"{where} declares shape {d.shape} ({declared} bytes), more than the "
            f"{DATASET_LIMIT} a dataset of a demo file may have"
        )
    return None


def check_float_array(d: h5py.Dataset, where: str, width: int | None = None) -> int:
    """The rows T of ``d``, a dataset of floats (T, D) with 1 <= T <= MAX_STEPS and D ==
    ``width`` (any D in 1..MAX_WIDTH when None), checked from its declared shape and dtype
    before it is read; InputError naming ``where`` otherwise."""
    expected = f"(T, {width if width is not None else 'D'}) floats, 1 <= T <= {MAX_STEPS}"
    if d.dtype.kind != "f" or d.dtype.byteorder == ">":
        raise InputError(f"{where} has dtype {d.dtype}, expected little-endian floats")
    shape = d.shape
    if (
        shape is None
        or len(shape) != 2
        or not 1 <= shape[0] <= MAX_STEPS
        or not 1 <= shape[1] <= MAX_WIDTH
        or (width is not None and shape[1] != width)
    ):
        raise InputError(f"{where} has shape {shape}, expected {expected}")
    return shape[0]


def check_seed(seed: int, where: str) -> int:
    """``seed`` when it is -1 (none given) or in SEED_RANGE; InputError naming ``where``."""
    low, high = SEED_RANGE
    if seed != -1 and not low <= seed <= high:
        raise InputError(f"{where} is {seed}, expected a reset seed in [{low}, {high}] or -1")
    return seed


def numbered(names: list[str], prefix: str, path: Path, where: str) -> list[str]:
    """``names``, each ``<prefix><n>`` with n a decimal integer written without leading
    zeros, ordered by n; InputError naming ``path`` and ``where`` (the group) for any
    other name, so that demo_01 and demo_1 are never read as one demo twice."""
    pattern = re.compile(re.escape(prefix) + r"(0|[1-9][0-9]{0,17})")
    for name in sorted(names):
        if not pattern.fullmatch(name):
            raise InputError(
                f"{path}: {where}{name}: not a {prefix}<n> name (n a whole number without "
                f"leading zeros); expected only {prefix}0, {prefix}1, ... there"
            )
    return sorted(names, key=lambda n: int(n[len(prefix) :]))
