"""Everything a file or the command line declares is bounded before it is used, and bad input
is one InputError line: Zarr stores' declared shapes, chunk counts and chunk sizes; JSON
files (not a regular file, too large, nested too deep); compare's input types and the
control characters of its names; a checkpoint's network sizes; names that become path
components; non-finite values in a dataset handed to robomimic."""

from __future__ import annotations

import argparse
import json
import os

import crc32c
import h5py
import numpy as np
import pytest
import torch
from numcodecs import Zstd

from mimicgen_pipe.core.errors import InputError
from mimicgen_pipe.data import outputs
from mimicgen_pipe.data.metrics import read_metrics
from mimicgen_pipe.data.store import open_store, read_store, write_store
from mimicgen_pipe.formats.exporters.robomimic import check_finite
from mimicgen_pipe.learn.policy import BCRNN, PolicyConfig
from mimicgen_pipe.learn.training import load_checkpoint, save_checkpoint
from mimicgen_pipe.report import compare
from mimicgen_pipe.stages import check_path_names
from mimicgen_pipe.stages.compare import read_shown

DEEP = "[" * 100_000 + "]" * 100_000


def small_store(tmp_path):
    """One episode of five steps: data/actions (5, 3) float32, one chunk."""
    steps = [{"actions": np.zeros((5, 3), np.float32)}]
    return write_store(tmp_path / "s.zarr", "source", steps, {"seed": np.array([1])}, {})


def declare(store, key: str, **fields) -> None:
    """Rewrite fields of ``key``'s zarr.json (shape, chunk_grid, ...)."""
    meta = store / key / "zarr.json"
    doc = json.loads(meta.read_text())
    doc.update(fields)
    meta.write_text(json.dumps(doc))


def grid(*chunks: int) -> dict:
    return {"name": "regular", "configuration": {"chunk_shape": list(chunks)}}


@pytest.mark.parametrize("read", [open_store, read_store])
def test_a_store_is_bounded_by_what_it_declares_before_any_read(tmp_path, read):
    store = small_store(tmp_path)
    declare(store, "data/actions", shape=[50, 3])  # rows the episode ends do not have
    with pytest.raises(InputError, match=r"data/actions: 50 steps, expected 5 \(meta/"):
        read(store)
    declare(store, "data/actions", shape=[5, 2 * 10**11], chunk_grid=grid(1, 1))
    with pytest.raises(InputError, match=r"data/actions: .* declares 1000000000000 chunks"):
        read(store)
    # a chunk file whose zstd header declares 10 MB where its shape holds 60 bytes: refused
    # before it is decoded
    declare(store, "data/actions", shape=[5, 3], chunk_grid=grid(5, 3))
    frame = Zstd().encode(bytes(10**7))
    (store / "data/actions/c/0/0").write_bytes(frame + np.uint32(crc32c.crc32c(frame)).tobytes())
    with pytest.raises(
        InputError, match=r"chunk 0\.0 declares 10000000 decoded bytes, expected 60"
    ):
        read_store(store)


def test_a_store_metadata_nested_too_deep_is_one_line(tmp_path):
    store = small_store(tmp_path)
    meta = store / "zarr.json"
    doc = json.loads(meta.read_text())
    meta.write_text(json.dumps(doc)[:-1] + ', "x": ' + DEEP + "}")
    with pytest.raises(InputError, match=r"zarr.json: damaged store metadata \(JSON nested"):
        open_store(store)


def test_json_readers_refuse_folders_large_files_and_deep_nesting(tmp_path):
    (tmp_path / "folder.json").mkdir()
    with pytest.raises(InputError, match=r"folder.json: cannot read the metrics file \(it is a"):
        read_metrics(tmp_path / "folder.json")
    deep = tmp_path / "deep.json"
    deep.write_text(DEEP)
    with pytest.raises(InputError, match=r"deep.json: JSON nested deeper than 100 levels"):
        read_metrics(deep)
    with pytest.raises(InputError, match=r"deep.json: not dvc exp show --json output \(JSON"):
        read_shown(str(deep))
    assert outputs.METRICS.why_not(deep) == "is not JSON"
    big = tmp_path / "big.json"
    with big.open("wb") as f:  # sparse: no disk taken
        f.truncate((64 << 20) + 1)
    with pytest.raises(InputError, match=r"big.json: 67108865 bytes, more than the 67108864"):
        read_metrics(big)


def test_compare_refuses_wrong_types_and_escapes_control_characters():
    shown = [{"rev": "abc", "data": {"params": [1, 2]}}]
    with pytest.raises(InputError, match=r"rev abc.data.params: expected a mapping, got a list"):
        compare.runs_of(shown, compare.PIPELINES["default"])
    with pytest.raises(InputError, match=r"--json: \[0\]: expected a mapping, got a str"):
        compare.runs_of(["x"], compare.PIPELINES["default"])
    text = compare.render([["", "exp\x1b]0;owned\x07\x9b"], ["k", "1"]])
    assert not any(ord(c) < 0x20 and c != "\n" or 0x7F <= ord(c) <= 0x9F for c in text)
    assert "exp\\x1b]0;owned\\x07\\x9b" in text


@pytest.mark.parametrize(
    "key, value", [("layers", 100_000), ("image_size", [40_000, 40_000]), ("seq_len", 10**9)]
)
def test_a_checkpoint_config_is_bounded_before_a_network_is_built(tmp_path, key, value):
    model = BCRNN(PolicyConfig(("eef_pos",), (3,), 7, hidden=4, layers=1))
    path = tmp_path / "a.pt"
    save_checkpoint(path, model, {"task": "stack_cube", "epoch": 1})
    ckpt = torch.load(path, weights_only=True)
    ckpt["config"][key] = value
    torch.save(ckpt, path)
    with pytest.raises(InputError, match=rf"a.pt: config.{key}: .* expected a value in \["):
        load_checkpoint(path)


@pytest.mark.parametrize(
    "dest, value", [("variant", "../../.."), ("task", "a/b"), ("data", ["D0", ".."])]
)
def test_names_that_become_path_components_are_checked(dest, value):
    args = argparse.Namespace(task=None, variant="D0", data=None)
    setattr(args, dest, value)
    with pytest.raises(InputError, match=rf"--{dest} '[./ab]+': expected letters, digits"):
        check_path_names(args)
    check_path_names(argparse.Namespace(task="stack_cube", variant="D1", data=["source"]))


def test_non_finite_values_are_refused_before_robomimic_reads_them(tmp_path):
    path = tmp_path / "demos.hdf5"
    with h5py.File(path, "w") as f:
        f["data/demo_0/actions"] = np.zeros((4, 7), np.float32)
        obs = np.zeros((4, 3), np.float32)
        obs[2, 1] = np.nan
        f["data/demo_0/obs/robot0_eef_pos"] = obs
        f["data/demo_0/obs/agentview_image"] = np.zeros((4, 2, 2, 3), np.uint8)
    with pytest.raises(InputError, match=r"data/demo_0/obs/robot0_eef_pos: NaN .* at step 2"):
        check_finite(path)
    os.remove(path)
    path.write_bytes(b"not hdf5")
    with pytest.raises(InputError, match=r"demos.hdf5: not a readable HDF5 file"):
        check_finite(path)
