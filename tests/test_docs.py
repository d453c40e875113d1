"""The documentation's pages run as written: every command and Python block of the getting-started page and the
tutorials, in order, page by page, in a fresh folder, with the training budgets cut to one generation (model-free)
or two iterations of two search generations (model-based). `pip install` lines are checked, not run: every extra
they name must exist."""

import re
import shlex
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from click.testing import CliRunner

import drrl.cli.commands
import drrl.training.train
from drrl.cli import main
from drrl.settings import Demonstrations, TrainConfig

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "docs" / "getting-started.md", *sorted((ROOT / "docs" / "tutorials").glob("*.md"))]
FENCE = re.compile(r'^```(\w+)(?: title="([^"]+)")?\n(.*?)^```$', re.MULTILINE | re.DOTALL)
EXTRAS = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"])


def blocks(page: Path) -> list[tuple[str, str | None, str]]:
    """(language, title, text) of each fenced block of ``page``, in order."""
    return [(m.group(1), m.group(2), m.group(3)) for m in FENCE.finditer(page.read_text())]


def commands(script: str) -> list[str]:
    """The shell commands of a block: lines joined at a trailing backslash, comments and blank lines dropped."""
    joined = re.sub(r"\\\n\s*", " ", script)
    return [line.split(" #")[0].strip() for line in joined.splitlines() if line.strip() and not line.startswith("#")]


def shortened(config: TrainConfig) -> TrainConfig:
    """``config`` with the least budget that still runs its loop: one generation (after a demonstration a round), or
    two model-based iterations of two generations, each fit a few updates long."""
    settings = config.model_based
    if settings is None:
        start = config.world.start
        demonstrations = min(start.episodes, start.rounds) if isinstance(start, Demonstrations) else 0
        budget = demonstrations + config.episodes_per_generation
        return config.updated(budget=budget, **({"demonstrations": demonstrations} if demonstrations else {}))
    quick = dict(fit_updates=5, refit_updates=5, frame_updates=5, frame_refit_updates=5)
    budget = settings.initial_episodes + settings.episodes_per_iteration
    return config.updated(budget=budget, model_based={"generations_per_iteration": 2, **quick})


def check_install(command: str) -> None:
    """A `pip install` line of the docs names only extras that exist."""
    for extras in re.findall(r"\[([\w,-]+)\]", command):
        assert set(extras.split(",")) <= EXTRAS, f"{command!r} names an extra that pyproject.toml lacks"


def run_command(command: str) -> None:
    words = shlex.split(command)
    if words[:2] == ["pip", "install"] or words[1:3] == ["-m", "pip"]:
        check_install(command)
    elif words[0] == "drrl":
        result = CliRunner().invoke(main, words[1:])
        assert result.exit_code == 0, f"{command}\n{result.output}"
    elif words[0] == "ray":
        ray(*words[1:])
    else:
        raise AssertionError(f"the docs test does not know how to run {command!r}")


def ray(*arguments: str) -> None:
    """Ray's command line, from this Python's environment."""
    subprocess.run([Path(sys.executable).with_name("ray"), *arguments], check=True, capture_output=True)


@pytest.mark.parametrize("page", PAGES, ids=[page.stem for page in PAGES])
@pytest.mark.slow
def test_every_block_of_the_page_runs(page, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "configs").symlink_to(ROOT / "configs")
    prepare = drrl.training.train.prepare

    def prepare_shortened(config, *args, **kwargs):
        return prepare(shortened(config), *args, **kwargs)

    monkeypatch.setattr(drrl.cli.commands, "prepare", prepare_shortened)
    monkeypatch.setattr(drrl.training.train, "prepare", prepare_shortened)
    ran, started_ray = 0, False
    try:
        for language, title, text in blocks(page):
            if title is not None:  # a file the page asks the reader to save
                (tmp_path / title).write_text(text)
            elif language == "bash":
                for command in commands(text):
                    started_ray |= command.startswith("ray start")
                    run_command(command)
                    ran += 1
            elif language == "python":
                exec(compile(text, f"{page.name}", "exec"), {"__name__": "__main__"})
                ran += 1
    finally:
        if started_ray:  # a page that fails after starting a cluster leaves none running
            ray("stop", "--force")
    assert ran, f"{page.name} has no command or Python block"


def test_shortened_budgets_still_run_the_loop():
    assert shortened(TrainConfig(popsize=6, episodes_per_candidate=2)).budget == 12
    model_based = shortened(TrainConfig(model_based={}))
    settings = model_based.model_based
    assert model_based.budget == settings.initial_episodes + settings.episodes_per_iteration
    assert settings.generations_per_iteration == 2
