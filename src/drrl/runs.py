"""The run folder a person can read: config.json, metrics.csv, checkpoint.safetensors, learning_curve.png.

Checkpoints are one safetensors file: the tensors of a nested state, with everything else as JSON in the file's
metadata. Nothing is ever pickled; a checkpoint is written to a temporary file and renamed, so a run killed while
writing keeps its previous checkpoint.
"""

from __future__ import annotations

import csv
import json
import os
from pathlib import Path
from typing import Any

import torch
from safetensors import SafetensorError, safe_open
from safetensors.torch import save_file

from drrl.config import TrainConfig

CONFIG = "config.json"
METRICS = "metrics.csv"
CHECKPOINT = "checkpoint.safetensors"
CURVE = "learning_curve.png"


class RunFolder:
    """One training run's files."""

    def __init__(self, path: Path | str):
        self.path = Path(path)

    @classmethod
    def create(cls, path: Path | str) -> RunFolder:
        """Make a new, empty run folder; refuse to write into one that holds files."""
        path = Path(path)
        if path.exists() and any(path.iterdir()):
            raise ValueError(f"run folder {path} already holds files; choose another --out")
        path.mkdir(parents=True, exist_ok=True)
        return cls(path)

    def write_config(self, config: TrainConfig) -> None:
        (self.path / CONFIG).write_text(config.model_dump_json(indent=2) + "\n")

    def read_config(self) -> TrainConfig:
        file = self.path / CONFIG
        if not file.is_file():
            raise ValueError(f"{self.path} is not a run folder: it has no {CONFIG}")
        return TrainConfig.model_validate_json(file.read_text())

    def append_metrics(self, row: dict[str, Any]) -> None:
        file = self.path / METRICS
        new = not file.exists()
        with file.open("a", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=list(row))
            if new:
                writer.writeheader()
            writer.writerow(row)

    def read_metrics(self) -> list[dict[str, float]]:
        with (self.path / METRICS).open(newline="") as handle:
            return [{key: float(value) for key, value in row.items()} for row in csv.DictReader(handle)]

    def save_checkpoint(self, state: dict[str, Any]) -> None:
        tensors: dict[str, torch.Tensor] = {}
        tree = _encode(state, "", tensors)
        temporary = self.path / (CHECKPOINT + ".tmp")
        save_file(tensors, temporary, metadata={"state": json.dumps(tree)})
        os.replace(temporary, self.path / CHECKPOINT)

    def load_checkpoint(self) -> dict[str, Any]:
        file = self.path / CHECKPOINT
        if not file.is_file():
            raise ValueError(f"{self.path} has no checkpoint ({CHECKPOINT})")
        try:
            with safe_open(file, framework="pt") as handle:
                tensors = {key: handle.get_tensor(key) for key in handle.keys()}
                tree = json.loads(handle.metadata()["state"])
            return _decode(tree, tensors)
        except (SafetensorError, OSError, KeyError, TypeError, ValueError) as error:
            raise ValueError(f"checkpoint {file} is unreadable (truncated or corrupted?): {error}") from None

    def plot_learning_curve(self, title: str) -> Path:
        """The centre policy's return against real training episodes, as the thesis's Figure 5.2."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        rows = [row for row in self.read_metrics() if row["center_return"] == row["center_return"]]
        figure, axes = plt.subplots(figsize=(6.4, 4.0))
        axes.plot([r["real_episodes"] for r in rows], [r["center_return"] for r in rows], label="centre policy μ")
        axes.plot([r["real_episodes"] for r in rows], [r["mean_return"] for r in rows], alpha=0.5,
                  label="population mean")
        axes.set_xlabel("real training episodes")
        axes.set_ylabel("average return")
        axes.set_title(title)
        axes.legend()
        axes.grid(alpha=0.3)
        figure.tight_layout()
        out = self.path / CURVE
        figure.savefig(out, dpi=120)
        plt.close(figure)
        return out


def _encode(value: Any, key: str, tensors: dict[str, torch.Tensor]) -> Any:
    """JSON-ready copy of ``value`` with tensors moved into ``tensors`` and dict keys' types kept."""
    if isinstance(value, torch.Tensor):
        tensors[key] = value.detach().cpu().contiguous().clone()
        return {"tensor": key}
    if isinstance(value, dict):
        return {"items": [[k, _encode(v, f"{key}/{k}", tensors)] for k, v in value.items()]}
    if isinstance(value, (list, tuple)):
        return {"list": [_encode(v, f"{key}/{i}", tensors) for i, v in enumerate(value)]}
    if value is None or isinstance(value, (bool, int, float, str)):
        return {"value": value}
    raise TypeError(f"cannot checkpoint a {type(value).__name__} at {key or 'top level'}")


def _decode(tree: Any, tensors: dict[str, torch.Tensor]) -> Any:
    if "tensor" in tree:
        return tensors[tree["tensor"]]
    if "items" in tree:
        return {k: _decode(v, tensors) for k, v in tree["items"]}
    if "list" in tree:
        return [_decode(v, tensors) for v in tree["list"]]
    return tree["value"]
