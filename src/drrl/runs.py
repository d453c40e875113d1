"""The run folder a person can read: config.json, metrics.csv, checkpoint.safetensors, learning_curve.png.

Checkpoints are one safetensors file: the tensors of a nested state, with everything else as JSON in the file's
metadata, and a SHA-256 digest of both, so that a damaged file is refused rather than loaded. Nothing is ever
pickled. Checkpoints and config.json are written to a temporary file and renamed, so a run killed while writing
keeps the previous version.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import os
import textwrap
import weakref
from itertools import pairwise
from pathlib import Path
from typing import Any

import torch
from pydantic import ValidationError
from safetensors import SafetensorError, safe_open
from safetensors.torch import save_file

try:
    import fcntl
except ImportError:  # not on Windows: run folders are then not held
    fcntl = None  # type: ignore[assignment]

from drrl.settings import TrainConfig, describe_errors, short_repr
from drrl.settings.flat import FLAT, is_flat, nested

CONFIG = "config.json"
METRICS = "metrics.csv"
CHECKPOINT = "checkpoint.safetensors"
CURVE = "learning_curve.png"
PICKLE_STARTS = (b"\x80", b"PK\x03\x04")  # a pickle (protocol 2 and later); torch.save's zip archive


class RunFolder:
    """One training run's files."""

    def __init__(self, path: Path | str):
        self.path = Path(path)
        self._hold: weakref.finalize | None = None

    @classmethod
    def create(cls, path: Path | str) -> RunFolder:
        """Make a new, empty run folder, held by this process (``claim``); refuse one that holds files."""
        path = Path(path)
        try:
            path.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise ValueError(f"cannot make run folder {path}: {error.strerror}; choose another --out") from None
        if not os.access(path, os.W_OK):
            raise ValueError(f"run folder {path} is not writable; choose another --out")
        folder = cls(path).claim()
        if any(path.iterdir()):
            folder.release()
            raise ValueError(f"run folder {path} already holds files; choose another --out")
        return folder

    def claim(self) -> RunFolder:
        """Hold the folder for this run: another process that tries to train or resume into it is refused until
        ``release`` or this process ends, however it ends (the operating system drops the hold of a killed
        process). A no-op where the platform has no ``flock``."""
        if fcntl is None or self._hold is not None:
            return self
        try:
            handle = os.open(self.path, os.O_RDONLY)
        except OSError as error:
            raise ValueError(f"cannot open run folder {self.path}: {error.strerror}") from None
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(handle)
            raise ValueError(
                f"run folder {self.path} is in use by another drrl process (training or resuming "
                f"it); wait for it to end, or choose another --out"
            ) from None
        self._hold = weakref.finalize(self, os.close, handle)
        return self

    def release(self) -> None:
        """Let other processes claim the folder again."""
        if self._hold is not None:
            self._hold()
            self._hold = None

    def write_config(self, config: TrainConfig) -> None:
        _write_atomically(self.path / CONFIG, config.model_dump_json(indent=2) + "\n")

    def read_config(self) -> TrainConfig:
        """config.json; one an older drrl wrote in the flat form is read as its run's settings (``recorded``)."""
        file = self.path / CONFIG
        if not file.is_file():
            raise ValueError(f"{self.path} is not a run folder: it has no {CONFIG}")
        try:
            return TrainConfig.model_validate(recorded(json.loads(file.read_bytes())))
        except (json.JSONDecodeError, UnicodeDecodeError) as error:
            raise ValueError(f"{file} is not JSON: {error}") from None
        except ValidationError as error:
            raise ValueError(f"{file} is not a valid drrl config:\n{describe_errors(error)}") from None

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

    def truncate_metrics(self, generations: int) -> list[dict[str, float]]:
        """Keep the rows of generations 1..``generations`` (drop those written after the last checkpoint)."""
        file = self.path / METRICS
        if generations == 0:
            file.unlink(missing_ok=True)
            return []
        try:
            with file.open(newline="") as handle:
                header, *rows = list(csv.reader(handle))
            kept = rows[:generations]
            whole = [row for row in kept if len(row) == len(header)]
            numbers = [[float(value) for value in row] for row in whole]
        except (OSError, ValueError, csv.Error) as error:
            raise ValueError(f"{file} is unreadable, so the run cannot be resumed exactly: {error}") from None
        if [int(row[0]) for row in numbers] != list(range(1, generations + 1)):
            raise ValueError(
                f"{file} holds {len(whole)} whole rows before the checkpoint's generation {generations}; "
                f"it needs one per generation to resume exactly"
            )
        text = io.StringIO()
        csv.writer(text).writerows([header, *kept])
        _write_atomically(file, text.getvalue())
        return [dict(zip(header, row, strict=True)) for row in numbers]

    def save_checkpoint(self, state: dict[str, Any]) -> None:
        tensors: dict[str, torch.Tensor] = {}
        tree = json.dumps(_encode(state, "", tensors))
        temporary = self.path / (CHECKPOINT + ".tmp")
        save_file(tensors, temporary, metadata={"state": tree, "sha256": _digest(tree, tensors)})
        os.replace(temporary, self.path / CHECKPOINT)

    def load_checkpoint(self) -> dict[str, Any]:
        file = self.path / CHECKPOINT
        if not file.is_file():
            raise ValueError(f"{self.path} has no checkpoint ({CHECKPOINT})")
        return read_checkpoint(file)

    def load_run(self) -> tuple[TrainConfig, dict[str, Any]]:
        """config.json and the checkpoint, refused unless the checkpoint was trained with exactly these settings
        (it records them): what eval, resume and render read."""
        config, checkpoint = self.read_config(), self.load_checkpoint()
        recorded = checkpoint.get("config")
        if not isinstance(recorded, dict):
            raise ValueError(
                f"checkpoint in {self.path} does not record the settings it was trained with (written "
                f"by an older drrl?), so it cannot be matched to its config.json"
            )
        changed = _differences(config.model_dump(mode="json"), _recorded_form(recorded))
        if changed:
            shown = "; ".join(
                f"{_setting_name(key)}: {short_repr(now, 60)} in {CONFIG}, {short_repr(then, 60)} when trained"
                for key, now, then in changed[:5]
            )
            raise ValueError(
                f"{self.path / CONFIG} differs from the settings its checkpoint was trained with "
                f"({shown}); restore it, or train a new run with the new settings"
            )
        return config, self._with_fit_state(checkpoint)

    def _with_fit_state(self, checkpoint: dict[str, Any]) -> dict[str, Any]:
        """``checkpoint``, where an older drrl wrote it for a model-based run without its model trainer's state, with
        that state as it was: the last fit's held-out loss, which that drrl read back from its last metrics row."""
        world = checkpoint.get("world")
        if checkpoint.get("kind") != "model-based" or not isinstance(world, dict) or "trainer" in world:
            return checkpoint
        try:
            rows = self.read_metrics()[: int(checkpoint["iteration"])]
        except (OSError, KeyError, TypeError, ValueError, csv.Error):
            return checkpoint  # refused as a checkpoint that does not fit, when restored
        last = rows[-1] if rows else {}
        loss = last.get("model_loss") if last.get("held_out_episodes") else None
        return checkpoint | {"world": world | {"trainer": {"last_loss": loss}}}

    def plot_learning_curve(
        self, title: str, best_step: int | None = None, eval_episodes: int | None = None, training: str | None = None
    ) -> Path:
        """learning_curve.png: ``learning_curve`` of this run's metrics."""
        import matplotlib.pyplot as plt

        figure = learning_curve(self.read_metrics(), title, best_step, eval_episodes, training)
        out = self.path / CURVE
        figure.savefig(out, dpi=120)
        plt.close(figure)
        return out


def learning_curve(
    rows: list[dict[str, float]],
    title: str,
    best_step: int | None = None,
    eval_episodes: int | None = None,
    training: str | None = None,
):
    """The centre policy's return against real training episodes, as the thesis's Figure 5.2: the measured centre
    (its ``best_step``, the one ``drrl eval`` runs, marked), the training episodes' mean return (``training`` says
    what that averages), for a model-based run the centre's return inside the model, and where a run with restarts
    started its search again. A matplotlib figure."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    measured = [row for row in rows if row["center_return"] == row["center_return"]]
    step = next(iter(rows[0])) if rows else "generation"  # the first column: generation or iteration
    model_based = bool(rows) and "imagined_center_return" in rows[0]
    figure, axes = plt.subplots(figsize=(6.4, 4.2), layout="constrained")
    over = f" (mean of {eval_episodes} measuring episodes)" if eval_episodes else ""
    axes.plot(
        [r["real_episodes"] for r in measured],
        [r["center_return"] for r in measured],
        marker=".",
        label=f"centre policy μ{over}",
    )
    if model_based:
        axes.plot(
            [r["real_episodes"] for r in rows],
            [r["imagined_center_return"] for r in rows],
            ls="--",
            alpha=0.7,
            label="centre μ inside the world model",
        )
    axes.plot(
        [r["real_episodes"] for r in rows],
        [r["mean_return"] for r in rows],
        alpha=0.5,
        label=training or ("real episodes collected, mean" if model_based else "candidates, mean (one episode each)"),
    )
    restarts = [
        before["real_episodes"] for before, row in pairwise(rows) if row.get("attempt") != before.get("attempt")
    ]
    for index, episodes in enumerate(restarts):
        axes.axvline(episodes, ls=":", color="grey", label=None if index else "the search starts again (restart_every)")
    best = [r for r in measured if best_step is not None and int(r[step]) == best_step]
    if best:
        axes.plot(
            best[0]["real_episodes"],
            best[0]["center_return"],
            "*",
            markersize=12,
            color="C3",
            label=f"best measured centre ({step} {best_step}, what drrl eval runs)",
        )
    axes.xaxis.set_major_locator(MaxNLocator(integer=True))
    axes.set_xlabel("real training episodes")
    axes.set_ylabel("return")
    axes.set_title(textwrap.fill(title, 85), fontsize=10)
    axes.legend(fontsize=8)
    axes.grid(alpha=0.3)
    return figure


def read_checkpoint(file: Path) -> dict[str, Any]:
    """A checkpoint's state; a damaged, foreign or pickled file raises ValueError saying which it is."""
    _check_layout(file)
    try:
        with safe_open(file, framework="pt") as handle:
            tensors = {key: handle.get_tensor(key) for key in handle.keys()}  # noqa: SIM118 (not iterable)
            metadata = handle.metadata() or {}
    except (SafetensorError, OSError) as error:
        raise ValueError(
            f"checkpoint {file} is truncated or has bytes appended: its data do not match its header ({error})"
        ) from None
    if "state" not in metadata:
        raise ValueError(f"checkpoint {file} holds no drrl state: not a drrl checkpoint")
    if "sha256" not in metadata:
        raise ValueError(
            f"checkpoint {file} has no SHA-256 digest, so its contents cannot be checked; drrl writes one "
            f"into every checkpoint"
        )
    if metadata["sha256"] != _digest(metadata["state"], tensors):
        raise ValueError(f"checkpoint {file} is corrupted: its contents do not match their SHA-256 digest")
    try:
        return _decode(json.loads(metadata["state"]), tensors)
    except RecursionError:
        raise ValueError(f"checkpoint {file} nests its state too deeply to be a drrl checkpoint") from None
    except (json.JSONDecodeError, KeyError, TypeError, AttributeError) as error:
        raise ValueError(f"checkpoint {file} has a malformed state ({type(error).__name__}: {error})") from None


def _check_layout(file: Path) -> None:
    """Refuse files that are not safetensors at all: empty, a pickle, no JSON header, a header cut short."""
    size = file.stat().st_size
    with file.open("rb") as handle:
        start = handle.read(9)
    if start[8:] != b"{":  # a safetensors file: 8 bytes of header length, then the JSON header
        if size < 9:
            raise ValueError(f"checkpoint {file} is {'empty' if size == 0 else f'truncated to {size} bytes'}")
        if start.startswith(PICKLE_STARTS):
            raise ValueError(f"checkpoint {file} is a pickle or torch.save file; drrl never loads pickles")
        raise ValueError(f"checkpoint {file} is not a safetensors file (no JSON header after its first 8 bytes)")
    header = int.from_bytes(start[:8], "little")
    if 8 + header > size:
        raise ValueError(
            f"checkpoint {file} is truncated: its header alone needs {header} bytes, the file holds "
            f"{size - 8} after the header's length"
        )


def _digest(tree: str, tensors: dict[str, torch.Tensor]) -> str:
    """SHA-256 of the JSON state and of every tensor's name, dtype, shape and bytes."""
    digest = hashlib.sha256(tree.encode())
    for key in sorted(tensors):
        tensor = tensors[key].contiguous()
        digest.update(f"{key}|{tensor.dtype}|{tuple(tensor.shape)}".encode())
        digest.update(tensor.reshape(-1).view(torch.uint8).numpy().tobytes())
    return digest.hexdigest()


def recorded(settings: Any) -> Any:
    """A run's settings as a run folder records them: the nested form, or an older drrl's flat form of every setting,
    migrated (what the run's parts do not have dropped, renamed settings renamed)."""
    return nested(settings, legacy=True) if is_flat(settings) else settings


def _recorded_form(settings: dict) -> dict:
    """The settings a checkpoint records, in the nested form as config.json holds them."""
    if not is_flat(settings):
        return settings
    try:
        return TrainConfig.model_validate(recorded(settings)).model_dump(mode="json")
    except ValidationError:
        return settings  # compared as it is: every setting then differs


def _setting_name(key: str) -> str:
    """A setting's flat name, for the place ``key`` (dotted) in the nested form, where it has one."""
    path = tuple(key.split("."))
    return next((setting.name for setting in FLAT.values() if setting.path == path), key)


def _differences(now: dict, then: dict, prefix: str = "") -> list[tuple[str, Any, Any]]:
    """(setting, value now, value then) for every setting of two nested settings dicts that differs."""
    found = []
    for key in sorted(now.keys() | then.keys()):
        a, b = now.get(key), then.get(key)
        if isinstance(a, dict) and isinstance(b, dict):
            found += _differences(a, b, f"{prefix}{key}.")
        elif a != b:
            found.append((f"{prefix}{key}", a, b))
    return found


def _write_atomically(file: Path, text: str) -> None:
    temporary = file.with_name(file.name + ".tmp")
    temporary.write_text(text)
    os.replace(temporary, file)


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
