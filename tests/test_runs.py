import pytest
import torch
from safetensors.torch import save_file

from drrl.config import TrainConfig
from drrl.runs import CHECKPOINT, RunFolder, _digest


def test_checkpoint_round_trip_keeps_tensors_values_and_key_types(tmp_path):
    run = RunFolder.create(tmp_path / "run")
    state = {"search": {"center": torch.arange(3.0), "rng": torch.arange(5, dtype=torch.uint8),
                        "optimizer": {0: {"step": torch.tensor(2.0), "betas": (0.9, 0.999)}}},
             "generation": 7, "name": "x", "flag": True, "nothing": None, "loss": float("inf")}
    run.save_checkpoint(state)
    loaded = run.load_checkpoint()
    assert torch.equal(loaded["search"]["center"], state["search"]["center"])
    assert loaded["search"]["rng"].dtype == torch.uint8
    assert list(loaded["search"]["optimizer"]) == [0]  # an int key stays an int
    assert loaded["search"]["optimizer"][0]["betas"] == [0.9, 0.999]
    assert (loaded["generation"], loaded["name"], loaded["flag"], loaded["nothing"]) == (7, "x", True, None)
    assert loaded["loss"] == float("inf")


def test_truncated_checkpoint_gives_a_clear_error(tmp_path):
    run = RunFolder.create(tmp_path / "run")
    run.save_checkpoint({"center": torch.zeros(100)})
    data = (run.path / CHECKPOINT).read_bytes()
    (run.path / CHECKPOINT).write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match="truncated"):
        run.load_checkpoint()


def test_a_checkpoint_refuses_objects_it_cannot_store_as_tensors_or_json(tmp_path):
    with pytest.raises(TypeError, match="cannot checkpoint a object"):
        RunFolder.create(tmp_path / "run").save_checkpoint({"bad": object()})


def test_create_refuses_a_folder_with_files(tmp_path):
    (tmp_path / "old.txt").write_text("keep me")
    with pytest.raises(ValueError, match="already holds files"):
        RunFolder.create(tmp_path)


def test_config_round_trips_through_the_run_folder(tmp_path):
    run = RunFolder.create(tmp_path / "run")
    config = TrainConfig(policy="mlp:4", budget=40, seed=3)
    run.write_config(config)
    assert run.read_config() == config


def test_a_checkpoint_whose_header_length_looks_like_a_pickle_still_loads(tmp_path):
    header_length_byte = 0x80  # the byte a pickle (protocol 2 and later) starts with
    folder = RunFolder.create(tmp_path / "run")
    for padding in range(256):  # the JSON header's length modulo 256 is its first byte on disk
        state = {"pad": "x" * padding, "center": torch.arange(3.0)}
        folder.save_checkpoint(state)
        if (folder.path / "checkpoint.safetensors").read_bytes()[0] == header_length_byte:
            break
    else:
        pytest.fail("no padding gave the wanted first byte")
    loaded = folder.load_checkpoint()
    assert loaded["pad"] == state["pad"] and torch.equal(loaded["center"], state["center"])


def test_a_checkpoint_nested_too_deeply_is_refused_with_a_message(tmp_path):
    folder = RunFolder(tmp_path)
    state = "{}"
    for _ in range(3000):
        state = '{"items": [["x", ' + state + ']]}'
    save_file({}, tmp_path / CHECKPOINT, metadata={"state": state, "sha256": _digest(state, {})})
    with pytest.raises(ValueError, match="nests its state too deeply"):
        folder.load_checkpoint()
