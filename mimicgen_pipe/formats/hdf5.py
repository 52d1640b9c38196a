"""HDF5 files written without the times HDF5 stamps on objects, so that the same content
gives the same bytes (the exporters write through these).

HDF5 records an object's creation and modification times where its creation property list
asks for them, which is HDF5's default. h5py turns them off for ``create_dataset`` (its
``track_times=False``) but not for ``create_virtual_dataset`` (the robomimic export's
``next_obs/<camera>_image``), whose times made two exports of one store differ; nor for
groups and the root group, which in the file format h5py writes by default carry none, but
would in a later one. Every object made here has them off.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import h5py


def create(path: Path) -> h5py.File:
    """A new file at ``path`` (truncated), open to write, as ``h5py.File(path, "w")`` makes
    it but with its root group's times off."""
    with h5py.File(path, "w") as probe:  # h5py's own property lists, its defaults in them
        fapl, fcpl = probe.id.get_access_plist(), probe.id.get_create_plist()
    fcpl.set_obj_track_times(False)
    return h5py.File(h5py.h5f.create(os.fsencode(path), h5py.h5f.ACC_TRUNC, fapl=fapl, fcpl=fcpl))


def group(parent: h5py.Group, path: str) -> h5py.Group:
    """``parent[path]``, each group on the way made where missing, without times."""
    for name in filter(None, path.split("/")):
        if name not in parent:
            gcpl = h5py.h5p.create(h5py.h5p.GROUP_CREATE)
            gcpl.set_obj_track_times(False)
            h5py.h5g.create(parent.id, *_link_name(name), gcpl=gcpl)
        parent = parent[name]
    return parent


def _link_name(name: str) -> tuple[bytes, h5py.h5p.PropLCID]:
    """``name`` encoded as h5py encodes a link's name (ASCII where it is; a UTF-8 name
    makes HDF5 write the group in its newer format), and its link creation list."""
    lcpl = h5py.h5p.create(h5py.h5p.LINK_CREATE)
    if name.isascii():
        lcpl.set_char_encoding(h5py.h5t.CSET_ASCII)
        return name.encode("ascii"), lcpl
    lcpl.set_char_encoding(h5py.h5t.CSET_UTF8)
    return name.encode("utf8"), lcpl


def dataset(parent: h5py.Group, path: str, **kwargs: Any) -> h5py.Dataset:
    """A new dataset at ``parent[path]`` (``create_dataset``'s ``kwargs``), the groups on
    the way made by :func:`group`, without times."""
    head, _, name = path.rpartition("/")
    return group(parent, head).create_dataset(name, track_times=False, **kwargs)


def virtual_layout(file: h5py.File, shape: tuple[int, ...], dtype: Any) -> h5py.VirtualLayout:
    """A virtual dataset's layout in ``file``, to fill and pass to :func:`virtual_dataset`:
    the dataset it makes has no times."""
    # the destination named up front: h5py then makes the dataset with layout.dcpl itself
    layout = h5py.VirtualLayout(shape, dtype, filename=file.filename)
    layout.dcpl.set_obj_track_times(False)
    return layout


def virtual_dataset(parent: h5py.Group, path: str, layout: h5py.VirtualLayout) -> h5py.Dataset:
    """A new virtual dataset at ``parent[path]`` of ``layout`` (:func:`virtual_layout`),
    the groups on the way made by :func:`group`."""
    head, _, name = path.rpartition("/")
    return group(parent, head).create_virtual_dataset(name, layout)
