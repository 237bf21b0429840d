"""Options from the settings dataclasses: one place per default and help, a config file, hidden knobs."""

from __future__ import annotations

import dataclasses
from typing import Annotated

import typer
from typer.testing import CliRunner

from laneprint.app.cli import app
from laneprint.options import SECTIONS, Section, Settings, config_reference, configurable, field_docs
from rl.drive.settings import DriveSettings
from rl.settings import DQNSettings

#: visible options (besides --help) a command may show at most
VISIBLE_AT_MOST = {"train": 12, "drive": 10, "crossval": 10, "analyze": 10, "personalize": 8}


def visible_options(command: str) -> list[str]:
    import typer

    click_cmd = typer.main.get_command(app).commands[command]  # type: ignore[attr-defined]
    return [
        p.opts[0]
        for p in click_cmd.params
        if not getattr(p, "hidden", False) and p.param_type_name == "option" and p.name != "help"
    ]


def test_every_field_of_every_section_has_help():
    for table, cls in SECTIONS.items():
        docs = field_docs(cls)
        missing = [f.name for f in dataclasses.fields(cls) if f.init and not docs.get(f.name)]
        assert not missing, f"[{table}] fields without a docstring or comment: {missing}"


def test_help_comes_from_the_dataclass():
    docs = field_docs(DQNSettings)
    assert docs["learning_rate"].startswith("eta, Adam step size")
    assert docs["episodes_per_approach"].endswith("see `resolved_episodes`")  # continuation comment lines
    assert field_docs(DriveSettings)["pace_by"].startswith("How the pace is read")  # a docstring


def test_visible_options_within_bounds():
    for command, most in VISIBLE_AT_MOST.items():
        shown = visible_options(command)
        assert "--config" in shown and len(shown) <= most, (command, shown)


def test_help_is_plain_text_and_undated():
    for command in VISIBLE_AT_MOST:
        out = CliRunner().invoke(app, [command, "--help"], terminal_width=200).output
        assert "README" not in out and "issue " not in out, command
    out = CliRunner().invoke(app, ["train", "--help"], terminal_width=200).output
    assert "'.[ray]'" in out and "[dqn]" in out  # not eaten as markup


def test_default_then_file_then_command_line(tmp_path):
    """A field's value: the dataclass default, then the file's table, then the command line (also under
    an older flag name); the command's own options read their `[command]` table unless given."""
    toy, got = typer.Typer(), {}

    @toy.command()
    @configurable("toy", Section("dqn", DQNSettings, aliases={"learning_rate": ("--lr",)}))
    def toy_command(settings: Settings, name: Annotated[str, typer.Option("--name")] = "a") -> None:
        got.update(dqn=settings.dqn, given=settings.given("dqn"), name=name)

    cfg = tmp_path / "c.toml"
    cfg.write_text('[dqn]\nlearning_rate = 0.002\ngamma = 0.9\n[toy]\nname = "from-file"\n')
    res = CliRunner().invoke(toy, ["--config", str(cfg), "--lr", "0.003"])
    assert res.exit_code == 0, res.output
    assert (got["dqn"].learning_rate, got["dqn"].gamma, got["dqn"].batch_size) == (0.003, 0.9, 256)
    assert got["given"] == {"learning_rate", "gamma"} and got["name"] == "from-file"
    CliRunner().invoke(toy, ["--config", str(cfg), "--name", "typed", "--no-double-q"])
    assert got["name"] == "typed" and got["dqn"].learning_rate == 0.002 and got["dqn"].double_q is False
    assert "--lr" not in CliRunner().invoke(toy, ["--help"]).output  # a research knob: hidden


def test_config_errors_are_one_line(tmp_path):
    cfg = tmp_path / "c.toml"
    for text, why in [
        ("[dqn]\nlearning_rat = 0.1\n", "did you mean learning_rate"),
        ("[crossval]\nlearnr = 'dqn'\n", "has no option 'learnr' (did you mean learner?)"),
        ('[dqn]\nbatch_size = "big"\n', "batch_size must be int"),
        ("[crossval]\nfolds = 1\n", "folds"),
    ]:
        cfg.write_text(text)
        res = CliRunner().invoke(app, ["crossval", "--all", "-w", str(tmp_path / "ws"), "--config", str(cfg)])
        assert res.exit_code == 1 and "Traceback" not in res.output, (text, res.output)
        assert why in res.output, (text, res.output)


def test_config_reference_lists_every_table():
    ref = config_reference()
    for table in ("dqn", "trees", "auto", "analysis", "crossval", "personalize", "drive"):
        assert f"## [{table}]" in ref
    assert "| `learning_rate` | float | `0.005` |" in ref


def test_a_section_option_in_the_command_table(tmp_path):
    """`[toy] lr_like = ...`: a section's option set in the command's own table (as `[train] episodes`),
    above the section's table and below the command line; a typo is named with the nearest key."""
    toy, got = typer.Typer(), {}

    @toy.command()
    @configurable("toy2", Section("dqn", DQNSettings, visible=("episodes",)))
    def toy_command(settings: Settings) -> None:
        got.update(dqn=settings.dqn, given=settings.given("dqn"))

    cfg = tmp_path / "c.toml"
    cfg.write_text("[dqn]\nepisodes = 10\ngamma = 0.5\n[toy2]\nepisodes = 20\n")
    assert CliRunner().invoke(toy, ["--config", str(cfg)]).exit_code == 0
    assert (got["dqn"].episodes, got["dqn"].gamma) == (20, 0.5) and "episodes" in got["given"]
    assert CliRunner().invoke(toy, ["--config", str(cfg), "--episodes", "30"]).exit_code == 0
    assert got["dqn"].episodes == 30
    cfg.write_text("[toy2]\nepisode = 20\n")
    res = CliRunner().invoke(toy, ["--config", str(cfg)])
    assert res.exit_code == 1 and "did you mean episodes" in res.output
