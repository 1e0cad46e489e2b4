"""The command line reads like a well-kept tool's: descriptions, defaults in help, newcomer options first,
splits said out loud, and no word of how the project was made in what a user reads."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest

from simharness.cli import build_parser, main

ROOT = Path(__file__).resolve().parents[1]
NEWCOMER = ["--data", "--model", "--out", "--epochs", "--device", "--init", "--force"]
HISTORY = re.compile(r"session|\bissue\s*#?\d", re.IGNORECASE)  # development history, not the product


def commands() -> dict[str, argparse.ArgumentParser]:
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def help_of(*argv: str, capsys: pytest.CaptureFixture[str]) -> str:
    with pytest.raises(SystemExit) as done:
        main([*argv, "--help"])
    assert done.value.code == 0
    return capsys.readouterr().out


@pytest.fixture(autouse=True)
def _columns(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("COLUMNS", "100")  # help wraps to the terminal: make the layout the same everywhere


def test_top_level_help_describes_the_tool_and_every_command(capsys) -> None:
    text = help_of(capsys=capsys)
    assert "evaluation harness for trajectory predictors" in text
    assert "argument parsing" not in text
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    for choice in sub._choices_actions:  # the one-line description in the command list
        assert choice.help and len(choice.help) < 100, choice.dest
        assert f"{choice.dest} " in text


def test_every_command_has_a_description() -> None:
    for name, parser in commands().items():
        assert parser.description and len(parser.description) > 20, name


def test_every_option_has_help_that_shows_its_default_or_is_a_flag() -> None:
    missing = []
    for name, parser in commands().items():
        formatter = parser._get_formatter()
        for action in parser._actions:
            if not action.option_strings or isinstance(action, argparse._HelpAction):
                continue
            text = formatter._expand_help(action) if action.help else ""
            flag = action.nargs == 0 and not isinstance(action, argparse.BooleanOptionalAction)
            if not action.help or not (flag or "default" in text or "(required)" in text):
                missing.append(f"{name} {action.option_strings[0]}: {text!r}")
    assert not missing, "\n".join(missing)


@pytest.mark.parametrize(("argv", "expected"), [
    (["train"], ["--epochs N maximum passes over the data (default: 16)", "(default: 0.001)",
                 "(default: --residual)"]),
    (["closedloop"], ["results folder (default: runs/closedloop)", "e.g. 0-19 or 1,5,9 (default: 0)"]),
    (["evaluate"], ["(default: test)", "(default: runs/evaluate/MODEL)"]),
])
def test_help_shows_the_defaults_a_user_asks_about(argv: list[str], expected: list[str], capsys) -> None:
    text = " ".join(help_of(*argv, capsys=capsys).split())
    for needle in expected:
        assert needle in text


def test_train_help_lists_the_newcomer_options_before_the_research_settings(capsys) -> None:
    text = help_of("train", capsys=capsys)
    body = text[text.index("options:"):]
    research = body.index("research settings")
    for option in NEWCOMER:
        assert re.search(rf"^\s+{option}\b", body[:research], re.MULTILINE), option
    for option in ["--lr-schedule", "--select", "--cv-gate", "--mean-loss", "--reannotate-noise", "--reannotate-drift",
                   "--correction-cost", "--test-scenes"]:
        assert re.search(rf"^\s+{option}\b", body[research:], re.MULTILINE), option
    assert len(text.splitlines()) < 90


def test_readme_starts_with_the_two_commands_and_fits_a_screen() -> None:
    lines = (ROOT / "README.md").read_text().splitlines()
    assert lines[2] == "```" and lines[3].startswith("make demo") and lines[4].startswith("make test")
    long = [f"line {i + 1}: {len(line)} characters" for i, line in enumerate(lines) if len(line) > 300]
    assert not long, long


def test_no_development_history_in_docs_or_help(capsys) -> None:
    docs = [ROOT / "README.md", *sorted((ROOT / "docs").glob("**/*.md"))]
    found = [f"{p.relative_to(ROOT)}:{i + 1}: {line.strip()}" for p in docs if p.name != "results.md"
             for i, line in enumerate(p.read_text().splitlines()) if HISTORY.search(line)]
    for name in ["", *commands()]:
        found += [f"simharness {name} --help: {line.strip()}" for line in
                  help_of(*([name] if name else []), capsys=capsys).splitlines() if HISTORY.search(line)]
    assert not found, "\n".join(found)


@pytest.fixture(scope="module")
def flow_data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from _predictor_data import write_flow_dataset

    return write_flow_dataset(tmp_path_factory.mktemp("cli") / "ds", scenes=5)


def test_evaluate_says_which_split_it_scores_and_how_many_scenes(flow_data: Path, tmp_path: Path, capsys) -> None:
    import json

    assert main(["evaluate", "--data", str(flow_data), "--model", "const-vel", "--out", str(tmp_path / "t")]) == 0
    out = capsys.readouterr().out
    scored = json.loads((tmp_path / "t" / "metrics.json").read_text())["scene_ids"]
    line = next(x for x in out.splitlines() if x.startswith("scoring split"))
    assert line.startswith(f"scoring split 'test': {len(scored)} of 5 scenes (")
    assert "--split all for every scene" in line and line.endswith(", ".join(scored))
    assert main(["evaluate", "--data", str(flow_data), "--model", "const-vel", "--out", str(tmp_path / "a"),
                 "--split", "all"]) == 0
    assert "scoring split 'all': 5 of 5 scenes" in capsys.readouterr().out


def test_train_says_what_it_holds_out_and_what_it_selects_on(flow_data: Path, tmp_path: Path, capsys) -> None:
    from predictor.split import split_scenes
    from simharness.io.parquet import Dataset

    args = ["train", "--data", str(flow_data), "--out", str(tmp_path / "run"), "--epochs", "2", "--warmup-epochs",
            "1", "--max-samples", "64", "--device", "cpu", "--reannotate-smooth", "0", "--reannotate-noise", "0"]
    assert main(args) == 0
    out = capsys.readouterr().out
    test = split_scenes(list(Dataset(flow_data).scene_ids))["test"]
    assert f"holding out {len(test)} of 5 scenes for test (hash split; pass --test-scenes to choose): " \
           f"{', '.join(test)}" in out
    assert "choosing the epoch on validation ADE" in out
    epochs = [x for x in out.splitlines() if x.startswith("epoch ")]
    assert len(epochs) == 2 and all("validation ADE " in x for x in epochs)
    assert f"simharness evaluate --data {flow_data} --model {tmp_path / 'run'}" in out
