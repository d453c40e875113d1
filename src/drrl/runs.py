"""The run folder a person can read: config.json, metrics.csv, checkpoint.safetensors, learning_curve.png.

Checkpoints are one safetensors file: the tensors of a nested state, with everything else as JSON in the file's
metadata, and a SHA-256 digest of both, so that a damaged file is refused rather than loaded. A checkpoint also
records the length and SHA-256 of the metrics rows it has seen, so that a folder is resumed only with those rows.
Nothing is ever pickled. Checkpoints and config.json are written to a temporary file and renamed, so a run killed
while writing keeps the previous version.
"""

from __future__ import annotations

import csv
import errno
import hashlib
import io
import json
import os
import re
import tempfile
import textwrap
import weakref
from contextlib import contextmanager
from dataclasses import dataclass
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
PATH_MAX, NAME_MAX = 4096, 255  # Linux's limits on a path and on one name in it, in bytes
PICKLE_STARTS = (b"\x80", b"PK\x03\x04")  # a pickle (protocol 2 and later); torch.save's zip archive


class RunFolder:
    """One training run's files."""

    def __init__(self, path: Path | str):
        self.path = Path(path)
        self._hold: weakref.finalize | None = None
        self._rows = Rows(0, hashlib.sha256())  # the metrics rows this process wrote or kept

    @classmethod
    def create(cls, path: Path | str) -> RunFolder:
        """Make a new, empty run folder, held by this process (``claim``); refuse one that holds files."""
        path = Path(path)
        try:
            check_writable(path, "run folder", folder=True)
            path.mkdir(parents=True, exist_ok=True)
        except (ValueError, OSError) as error:
            why = error.strerror if isinstance(error, OSError) else error
            raise ValueError(f"{why}; choose another --out") from None
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
        """One metrics row, appended; its bytes are added to the digest the next checkpoint records (``_rows``)."""
        file = self.path / METRICS
        text = io.StringIO()
        writer = csv.DictWriter(text, fieldnames=list(row))
        if self._rows.count == 0 and not file.exists():
            writer.writeheader()
        writer.writerow(row)
        data = text.getvalue().encode()
        with writing(file), file.open("ab") as handle:
            handle.write(data)
        self._rows = self._rows.then(data)

    def read_metrics(self) -> list[dict[str, float]]:
        """metrics.csv's rows, as numbers."""
        file = self.path / METRICS
        try:
            data = file.read_bytes()
        except OSError as error:
            raise ValueError(f"cannot read {file}: {error.strerror}") from None
        return parse_metrics(file, data)

    def truncate_metrics(self, generations: int, record: dict | None = None) -> list[dict[str, float]]:
        """Keep the rows of generations 1..``generations``, those the checkpoint recorded (``record``: their bytes'
        length and SHA-256), and drop those written after it. Rows that are not the ones recorded (edited, cut, another
        run's) are refused: a resumed run would write them into its own record."""
        file = self.path / METRICS
        if generations and not file.is_file():
            raise ValueError(f"{file} is missing; it needs one row per generation to resume exactly")
        try:
            data = file.read_bytes() if generations else b""
        except OSError as error:
            raise ValueError(f"cannot read {file}: {error.strerror}") from None
        if record is None:  # an older drrl's checkpoint: the rows are checked for their order only
            kept = _first_rows(data, generations)
        else:
            kept = data[: record["bytes"]]
            if record["rows"] != generations or hashlib.sha256(kept).hexdigest() != record["sha256"]:
                raise ValueError(
                    f"{file} is not the one its checkpoint recorded: its first {generations} rows were edited, cut "
                    f"or come from another run; restore it, or train a new run"
                )
        rows = parse_metrics(file, kept)
        if len(rows) != generations:
            raise ValueError(
                f"{file} holds {len(rows)} rows before the checkpoint's generation {generations}; it needs one per "
                f"generation to resume exactly"
            )
        if kept:
            _write_atomically(file, kept)
        else:
            file.unlink(missing_ok=True)
        self._rows = Rows(generations, hashlib.sha256(kept), len(kept))
        return rows

    def save_checkpoint(self, state: dict[str, Any]) -> None:
        """The state, with the record of the metrics rows it has seen (``state["iteration"]`` of them), so that the
        folder is resumed only with those rows."""
        if "iteration" in state:
            state = state | {"metrics": self._metrics_record(state["iteration"])}
        tensors: dict[str, torch.Tensor] = {}
        tree = json.dumps(_encode(state, "", tensors))
        temporary = self.path / (CHECKPOINT + ".tmp")
        with writing(temporary):
            save_file(tensors, temporary, metadata={"state": tree, "sha256": _digest(tree, tensors)})
        os.replace(temporary, self.path / CHECKPOINT)

    def _metrics_record(self, rows: int) -> dict | None:
        """The length and SHA-256 of metrics.csv's header and first ``rows`` rows; None where it has fewer."""
        if isinstance(rows, bool) or not isinstance(rows, int) or rows < 0:
            return None  # not a state of the loop's: refused when read
        for known in (self._rows, self._rows.before):
            if known is not None and known.count == rows:
                return known.record()
        file = self.path / METRICS
        data = file.read_bytes() if file.exists() else b""
        if rows and len(data.splitlines()) <= rows:
            return None
        kept = _first_rows(data, rows)
        return Rows(rows, hashlib.sha256(kept), len(kept)).record()

    def load_checkpoint(self) -> dict[str, Any]:
        file = self.path / CHECKPOINT
        if self.stopped_before_its_first_checkpoint():
            raise ValueError(
                f"{self.path} has no checkpoint: its run stopped before the first; drrl train --resume {self.path} "
                f"starts it again"
            )
        if not file.is_file():
            raise ValueError(f"{self.path} has no checkpoint ({CHECKPOINT})")
        return read_checkpoint(file)

    def stopped_before_its_first_checkpoint(self) -> bool:
        """Whether the folder holds a run's settings but neither a checkpoint nor metrics (the first checkpoint comes
        before the first row): it was stopped (killed) while starting, not damaged later."""
        return (self.path / CONFIG).is_file() and not any((self.path / name).exists() for name in (CHECKPOINT, METRICS))

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


@dataclass(frozen=True)
class Rows:
    """The metrics rows written so far: how many, the SHA-256 and length of their bytes with the header's, and the
    same before the last row (a checkpoint taken on an interrupt records the last whole step, one row back)."""

    count: int
    digest: Any  # a hashlib sha256 object
    size: int = 0
    before: Rows | None = None

    def then(self, data: bytes) -> Rows:
        digest = self.digest.copy()
        digest.update(data)
        return Rows(self.count + 1, digest, self.size + len(data), Rows(self.count, self.digest, self.size))

    def record(self) -> dict:
        return {"rows": self.count, "bytes": self.size, "sha256": self.digest.hexdigest()}


def _first_rows(data: bytes, rows: int) -> bytes:
    """metrics.csv's header and first ``rows`` rows, as written; nothing for none."""
    return b"".join(data.splitlines(keepends=True)[: rows + 1]) if rows else b""


def parse_metrics(file: Path, data: bytes) -> list[dict[str, float]]:
    """metrics.csv's bytes as rows of numbers; a row or value that is not one raises ValueError naming it."""
    try:
        header, *rows = list(csv.reader(io.StringIO(data.decode())))
    except ValueError:  # no header (an empty file), or bytes that are not UTF-8
        return [] if not data else _bad_metrics(file, "its bytes are not a CSV table of numbers")
    except csv.Error as error:
        return _bad_metrics(file, str(error))
    parsed = []
    for number, row in enumerate(rows, start=2):
        if len(row) != len(header):
            return _bad_metrics(file, f"line {number} has {len(row)} values for {len(header)} columns")
        try:
            values = [float(value) for value in row]
        except ValueError:
            return _bad_metrics(file, f"line {number} holds a value that is not a number")
        if not (values and values[0] == number - 1):
            return _bad_metrics(file, f"line {number}'s {header[0]} is {row[0]!r}, not {number - 1}")
        parsed.append(dict(zip(header, values, strict=True)))
    return parsed


def _bad_metrics(file: Path, why: str):
    raise ValueError(f"{file} is damaged ({why}), so the run cannot be resumed or plotted exactly")


@contextmanager
def writing(file: Path):
    """Turn what the operating system refuses while ``file`` is written (a full disk, a file too large, a read-only
    folder) into an OSError naming the file, which callers report in one line; a partly written temporary file is
    removed, so the last whole one stays."""
    try:
        yield
    except (OSError, SafetensorError) as error:
        if file.name.endswith(".tmp"):
            file.unlink(missing_ok=True)
        if isinstance(error, OSError):
            raise
        code = re.search(r"(?:code: |os error )(\d+)", str(error))
        number = int(code.group(1)) if code else errno.EIO
        raise OSError(number, os.strerror(number), str(file)) from None


def check_writable(path: Path, what: str, folder: bool) -> None:
    """Refuse, before any work, a place drrl could not write ``what`` to: a path or a name longer than the system
    allows, a file where a folder is needed, or a folder in which nothing can be created (read-only, /proc). Folders
    still missing are left to the writer to make."""
    path = Path(path)
    size = len(os.fsencode(path))
    if size >= PATH_MAX:
        raise ValueError(f"{what} is a path of {size} bytes; the system allows at most {PATH_MAX - 1}")
    longest = max(path.parts, key=lambda part: len(os.fsencode(part)), default="")
    if len(os.fsencode(longest)) > NAME_MAX:
        raise ValueError(
            f"{what} {short_repr(str(path), 60)} has a name of {len(os.fsencode(longest))} bytes "
            f"({short_repr(longest, 30)}); the system allows at most {NAME_MAX}"
        )
    if path.exists() and path.is_dir() != folder:
        raise ValueError(
            f"{what} {path} is {'a file' if folder else 'a folder'}; give {'a folder' if folder else 'a file'}"
        )
    place = path if folder else path.parent
    while not place.exists() and place != place.parent:
        place = place.parent
    if not place.is_dir():
        raise ValueError(f"{what} {path} lies under {place}, which is a file, not a folder")
    try:
        with tempfile.TemporaryFile(dir=place):
            pass
    except OSError as error:
        raise ValueError(f"cannot write {what} {path}: nothing can be made in {place} ({error.strerror})") from None


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
    """The settings a checkpoint records, in the nested form as config.json holds them, with the defaults of settings
    added since (a setting the run did not know ran as its default)."""
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


def _write_atomically(file: Path, content: str | bytes) -> None:
    temporary = file.with_name(file.name + ".tmp")
    with writing(temporary):
        temporary.write_bytes(content.encode() if isinstance(content, str) else content)
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
