"""User errors end a command with one line naming the option, a non-zero exit and no traceback,
before any work starts; outputs never overwrite an existing file without ``--force``."""

import json
import shutil
from pathlib import Path

import pytest

from marlander_lite import cli
from marlander_lite.cli import is_user_error, main
from marlander_lite.policy_file import PolicyFileError
from marlander_lite.training import train as train_module
from marlander_lite.training.presets import get_preset
from marlander_lite.training.train import train

POLICY = Path(__file__).resolve().parents[1] / "data" / "policies" / "quick-cpu.safetensors"
BINARY = bytes(range(256)) * 4


def tiny(steps: int):
    """A training run of a second or two."""
    small = {"num_envs": 64, "n_steps": 32, "batch_size": 512, "net_arch": (16, 16), "checkpoint_every": 0}
    return get_preset("quick-cpu").replace(total_steps=steps, torch_threads=1, **small)


def fails(capsys, argv: list[str], *needles: str) -> str:
    """Run ``marlander argv``; it must exit 2 with one error line holding every needle."""
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = [line for line in err.splitlines() if "error:" in line]
    assert len(lines) == 1, err
    for needle in needles:
        assert needle in lines[0], (needle, err)
    return lines[0]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A tiny finished training run."""
    return train(tiny(2048), tmp_path_factory.mktemp("runs") / "run").root


def copy_run(run, tmp_path) -> Path:
    shutil.copytree(run, tmp_path / "copy")
    return tmp_path / "copy"


# ---------------------------------------------------------------------------- train and quickstart


def test_train_into_an_existing_run_is_refused_in_one_line(capsys, run):
    fails(capsys, ["train", "--out", str(run), "--steps", "100"], "--out", "already holds a training run")


def test_a_family_opening_without_a_family_or_beyond_its_range_is_refused_with_the_fix(capsys, tmp_path):
    out = ["--out", str(tmp_path / "run")]
    opening = ["train", "--preset", "quick-cpu-slow-trackers", *out]
    fails(capsys, [*opening, "--family-opening", "1.5"], "family_opening must be a fraction of total_steps in [0, 1]")
    fails(capsys, [*opening, "--family-opening-gate", "-0.1"], "family_opening_gate must be a success rate in [0, 1]")
    fails(capsys, [*opening, "--dynamics", "{}"], "family_opening needs a dynamics family", "set family_opening to 0")
    assert not (tmp_path / "run").exists()


def test_quickstart_into_an_existing_run_is_refused_before_training(capsys, run):
    fails(capsys, ["quickstart", "--out", str(run)], "--out", "already holds a training run")


@pytest.mark.parametrize(
    ("argv", "flag", "allowed"),
    [
        (["train", "--seed", "-1"], "--seed", "non-negative integer"),
        (["train", "--steps", "0"], "--steps", "positive integer"),
        (["quickstart", "--episodes", "0"], "--episodes", "positive integer"),
        (["quickstart", "--seed", "-3"], "--seed", "non-negative integer"),
        (["evaluate", "p.safetensors", "--episodes", "-2"], "--episodes", "positive integer"),
        (["export", "RUN", "--checkpoint", "x"], "--checkpoint", "non-negative integer"),
    ],
)
def test_bad_numbers_name_the_option_and_write_nothing(capsys, tmp_path, monkeypatch, argv, flag, allowed):
    monkeypatch.chdir(tmp_path)
    fails(capsys, [*argv, "--out", "run"] if argv[0] == "train" else argv, f"argument {flag}", allowed)
    assert list(tmp_path.iterdir()) == []  # no run folder, no config.json


def test_resume_refuses_other_options_and_runs_it_cannot_resume(capsys, run, tmp_path):
    fails(capsys, ["train", "--resume", str(run), "--steps", "10"], "--resume", "drop --steps")
    fails(capsys, ["train", "--resume", str(tmp_path)], "--resume", "no config.json")
    fails(capsys, ["train", "--resume", str(run)], "--resume", "already finished")
    copy = copy_run(run, tmp_path)
    record = json.loads((copy / "config.json").read_text())
    del record["finished"]
    (copy / "config.json").write_text(json.dumps(record))
    fails(capsys, ["train", "--resume", str(copy)], "--resume", "no interrupt checkpoint")


def test_a_binary_config_file_is_one_line(capsys, run, tmp_path):
    copy = copy_run(run, tmp_path)
    (copy / "config.json").write_bytes(BINARY)
    fails(capsys, ["train", "--resume", str(copy)], "--resume", "not a readable JSON file")
    fails(capsys, ["export", str(copy), "--force"], "not a readable JSON file")


@pytest.mark.parametrize("failure", [RuntimeError("boom"), KeyboardInterrupt()])
def test_a_start_that_fails_leaves_nothing_that_blocks_a_retry(tmp_path, monkeypatch, failure):
    def broken(*args, **kwargs):
        raise failure

    with monkeypatch.context() as patch:
        patch.setattr(train_module, "make_training_env", broken)
        with pytest.raises(type(failure)):
            train(tiny(2048), tmp_path / "run")
    assert not (tmp_path / "run").exists()
    (tmp_path / "given").mkdir()  # a folder the user made: kept, emptied of what train wrote
    with monkeypatch.context() as patch:
        patch.setattr(train_module, "make_training_env", broken)
        with pytest.raises(type(failure)):
            train(tiny(2048), tmp_path / "given")
    assert list((tmp_path / "given").iterdir()) == []
    assert train(tiny(2048), tmp_path / "run").policy.is_file()  # the same --out works now


# ---------------------------------------------------------------------------- outputs: --force


def test_evaluate_json_refuses_a_directory_an_existing_file_and_the_policy(capsys, tmp_path):
    base = ["evaluate", str(POLICY), "--episodes", "2"]
    fails(capsys, [*base, "--json", str(tmp_path)], "--json", "is a directory")
    fails(capsys, [*base, "--json", str(POLICY), "--force"], "--json", "a file this command reads")
    summary = tmp_path / "summary.json"
    summary.write_text("keep me")
    fails(capsys, [*base, "--json", str(summary)], "--json", "already exists; pass --force")
    assert summary.read_text() == "keep me"
    assert main([*base, "--json", str(summary), "--force"]) == 0
    assert json.loads(summary.read_text())["episodes"] == 2


def test_export_refuses_a_directory_an_existing_file_and_its_inputs(capsys, run, tmp_path):
    copy = copy_run(run, tmp_path)
    fails(capsys, ["export", str(copy), "--out", str(tmp_path)], "--out", "is a directory")
    fails(capsys, ["export", str(copy), "--out", str(copy / "model.zip"), "--force"], "a file this command reads")
    before = (copy / "policy.safetensors").read_bytes()
    fails(capsys, ["export", str(copy)], "--out", "policy.safetensors already exists; pass --force")
    assert (copy / "policy.safetensors").read_bytes() == before
    assert main(["export", str(copy), "--out", str(tmp_path / "p.safetensors")]) == 0
    assert main(["export", str(copy), "--force"]) == 0
    fails(capsys, ["export", str(copy), "--checkpoint", "7"], "No model at")


def test_plot_refuses_other_csvs_directories_missing_suffixes_and_existing_images(capsys, run, tmp_path):
    other = tmp_path / "other.csv"
    other.write_text("a,b\n1,2\n")
    fails(capsys, ["plot", "curves", str(other), "--out", str(tmp_path / "x.png")], "is not a training log")
    binary = tmp_path / "binary.csv"
    binary.write_bytes(BINARY)
    fails(capsys, ["plot", "curves", str(binary), "--out", str(tmp_path / "x.png")], "is not a training log")
    fails(capsys, ["plot", "curves", str(run), "--out", str(tmp_path)], "--out", "is a directory")
    fails(capsys, ["plot", "curves", str(run), "--out", str(tmp_path / "figure")], "--out", "must end in .png")
    image = tmp_path / "curves.png"
    image.write_text("keep me")
    fails(capsys, ["plot", "curves", str(run), "--out", str(image)], "already exists; pass --force")
    assert image.read_text() == "keep me"
    assert main(["plot", "curves", str(run), "--out", str(image), "--force"]) == 0
    assert image.read_bytes().startswith(b"\x89PNG")
    assert f"Wrote {image}" in capsys.readouterr().out
    assert not list(tmp_path.glob("*.png.png"))


# ---------------------------------------------------------------------------- main()


def test_ctrl_c_during_start_up_exits_130_without_a_traceback(capsys, monkeypatch):
    def interrupted(name):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli.importlib, "import_module", interrupted)
    assert main(["train", "--list"]) == 130
    err = capsys.readouterr().err
    assert err == "Interrupted.\n"


def test_library_errors_are_one_line(capsys, tmp_path):
    from marlander_lite.deploy.link import LinkError
    from marlander_lite.deploy.schema import ConfigError

    for error in (ConfigError("x"), PolicyFileError("x"), LinkError("x"), FileExistsError("x")):
        assert is_user_error(error)
    assert not is_user_error(RuntimeError("a bug"))
    broken = tmp_path / "broken.safetensors"
    broken.write_bytes(BINARY)
    fails(capsys, ["evaluate", str(broken), "--episodes", "2"], "broken.safetensors")
    config = tmp_path / "lab.yaml"
    config.write_bytes(BINARY)
    fails(capsys, ["deploy", "--sim", "--config", str(config), "--policy", str(POLICY)], "lab.yaml")


def _commands(parser, prefix=()):
    """Every (sub)command path of the CLI, found in argparse's own parser tree."""
    import argparse

    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield (*prefix, name)
                yield from _commands(sub, (*prefix, name))


def test_every_command_prints_its_help(capsys: pytest.CaptureFixture[str]) -> None:
    """argparse %-formats help text: a literal '%' in a help string breaks --help of that command."""
    commands = list(_commands(cli.build_parser()))
    assert ("transfer",) in commands and ("plot", "profiles") in commands
    for command in commands:
        try:
            code = main([*command, "--help"])  # 'train --help' prints the preset's values, then returns
        except SystemExit as stop:
            code = stop.code
        assert code == 0, command
        assert "usage: marlander" in capsys.readouterr().out
