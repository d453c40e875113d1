import numpy as np
import pytest
import torch
from safetensors.torch import save_file

from drrl.runs import CHECKPOINT, RunFolder, _digest
from drrl.settings import TrainConfig


def test_checkpoint_round_trip_keeps_tensors_values_and_key_types(tmp_path):
    run = RunFolder.create(tmp_path / "run")
    state = {
        "search": {
            "center": torch.arange(3.0),
            "rng": torch.arange(5, dtype=torch.uint8),
            "optimizer": {0: {"step": torch.tensor(2.0), "betas": (0.9, 0.999)}},
        },
        "generation": 7,
        "name": "x",
        "flag": True,
        "nothing": None,
        "loss": float("inf"),
    }
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
        state = '{"items": [["x", ' + state + "]]}"
    save_file({}, tmp_path / CHECKPOINT, metadata={"state": state, "sha256": _digest(state, {})})
    with pytest.raises(ValueError, match="nests its state too deeply"):
        folder.load_checkpoint()


def overlapping(labels) -> bool:
    boxes = [label.get_window_extent() for label in labels if label.get_text()]
    return any(a.overlaps(b) for i, a in enumerate(boxes) for b in boxes[i + 1 :])


def assert_reads_cleanly(figure, whole_x: bool = True):
    """What a reader needs of a figure: its title, axis labels and legend inside the canvas, no two tick labels
    overlapping, and (``whole_x``) x ticks at whole numbers only, as episodes and steps are counted."""
    figure.canvas.draw()
    canvas = figure.bbox
    for axes in figure.axes:
        legends = [*figure.legends, *([axes.get_legend()] if axes.get_legend() else [])]
        for text in (axes.title, axes.xaxis.label, axes.yaxis.label, *legends):
            box = text.get_window_extent()
            assert canvas.contains(*box.p0) and canvas.contains(*box.p1), f"{text} is cut off"
        shown = shown_ticks(axes)
        assert shown and not overlapping(shown) and not overlapping(axes.get_yticklabels())
        if whole_x:
            assert all(float(label.get_position()[0]).is_integer() for label in shown), [t.get_text() for t in shown]


def shown_ticks(axes) -> list:
    """The x tick labels drawn inside the axes' limits."""
    low, high = axes.get_xlim()
    return [label for label in axes.get_xticklabels() if label.get_text() and low <= label.get_position()[0] <= high]


@pytest.mark.parametrize("kind", ["model-free", "model-based", "action-space"])
def test_the_learning_curve_reads_cleanly(kind):
    from drrl.runs import learning_curve

    model_based = kind == "model-based"
    rows = [
        {
            "iteration" if model_based else "generation": k,
            "real_episodes": 2 * k,
            "mean_return": -300.0 + 40 * k,
            "center_return": -250.0 + 35 * k if model_based or k % 3 == 0 else float("nan"),
            **({"imagined_center_return": -200.0 + 20 * k} if model_based else {}),
        }
        for k in range(1, 4)
    ]
    title = "drrl/CartPole-v0, linear:nobias policy, model-based pgpe (rnn 64, K = 1), a title long enough to wrap"
    training = "exploring episodes, mean" if kind == "action-space" else None
    figure = learning_curve(rows, title, best_step=3, eval_episodes=50, training=training)
    assert_reads_cleanly(figure)
    axes = figure.axes[0]
    labels = [text.get_text() for text in axes.get_legend().get_texts()]
    assert labels[0] == "centre policy μ (mean of 50 measuring episodes)"
    assert any("best measured centre" in label and "what drrl eval runs" in label for label in labels)
    assert ("centre μ inside the world model" in labels) == model_based
    assert ("exploring episodes, mean" in labels) == (kind == "action-space")
    assert len(axes.lines[-2].get_xdata()) == 3  # the training episodes at every step, measured or not


def test_the_comparison_figure_reads_cleanly():
    import numpy as np

    from drrl.compare import METHODS, Curve, comparison_figure

    episodes = np.array([2, 3, 4, 6, 8, 16, 40, 100, 300])
    curves = [Curve(name, episodes, -300.0 + episodes, -310.0 + episodes, -290.0 + episodes, 3) for name in METHODS]
    figure = comparison_figure(curves, "cartpole", 50)
    assert_reads_cleanly(figure)
    axes = figure.axes[0]
    assert [label.get_text() for label in shown_ticks(axes)] == ["2", "5", "10", "20", "50", "100", "200"]
    (legend,) = figure.legends
    assert [text.get_text() for text in legend.get_texts()] == [f"{name} (3 seeds)" for name in METHODS]
    assert legend.get_window_extent().y1 < axes.get_window_extent().y0  # below the axes, hiding no curve
    assert len(axes.collections) == len(METHODS)  # a shaded standard-error band per method


def test_the_k_step_error_figure_reads_cleanly():
    import numpy as np

    from drrl.models.quality import k_step_figure

    figure = k_step_figure({"m = 0": np.geomspace(0.1, 30, 20), "overshooting": np.geomspace(0.1, 3, 20)}, "errors")
    assert_reads_cleanly(figure)


def test_a_method_measured_once_is_drawn_as_a_marker():
    from drrl.compare import Curve, comparison_figure

    one = np.array([16.0])
    two = np.array([16.0, 32.0])
    curves = [Curve("ppo", one, one - 300, one - 310, one - 290, 1), Curve("pgpe", two, two, two, two, 1)]
    figure = comparison_figure(curves, "cartpole", 50)
    ppo, pgpe = figure.axes[0].get_lines()
    assert ppo.get_marker() == "o" and ppo.get_xdata().tolist() == [16.0] and pgpe.get_marker() in ("None", None, "")
