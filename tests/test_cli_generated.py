"""The command line generated from the typed configs: every field an option with its docstring as help, the
preset applied first and only the options given on top, one-line errors naming the option and what it takes."""

import dataclasses
import json
import re
from pathlib import Path

import pytest

from marlander_lite.cli import build_parser, main
from marlander_lite.config_cli import changed_options, field_docs, plain
from marlander_lite.experiments.apf import APFConfig
from marlander_lite.experiments.commands import command_line, config_from_args
from marlander_lite.experiments.protocol import ProtocolConfig
from marlander_lite.task import TaskConfig
from marlander_lite.training import evaluation
from marlander_lite.training import train as train_module
from marlander_lite.training.presets import PRESETS, TrainConfig, get_preset

ROOT = Path(__file__).resolve().parents[1]
POLICY = ROOT / "data" / "policies" / "quick-cpu.safetensors"


def help_of(capsys, argv: list[str]) -> str:
    assert main(argv) == 0 if argv[0] == "train" else _exits_zero(argv)
    return capsys.readouterr().out


def _exits_zero(argv: list[str]) -> bool:
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    return exit_info.value.code == 0


def entry(help_text: str, flag: str) -> str:
    """The help entry of ``flag`` (from its line to the next option), whitespace removed."""
    match = re.search(rf"^  {re.escape(flag)}[ ,\n].*?(?=^  -|^\S|\Z)", help_text, flags=re.M | re.S)
    assert match, f"{flag} not in the help"
    return "".join(match.group(0).split())


def squeezed(text: str) -> str:
    return "".join(text.split())


def fails(capsys, argv: list[str], *needles: str) -> str:
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert err.startswith(f"marlander {argv[0]}: error: "), err
    for needle in needles:
        assert needle in err, (needle, err)
    return err


@pytest.fixture
def no_training(monkeypatch):
    """``marlander train`` up to the call of train(); the config it would train is recorded instead."""
    seen = []

    def record(config, out, **kwargs):
        seen.append(config)
        return train_module.RunFiles(Path(out))

    monkeypatch.setattr(train_module, "train", record)
    return seen


# ---------------------------------------------------------------------------- docstrings


def test_field_docs_reads_the_string_under_each_field():
    docs = field_docs(TrainConfig)
    assert list(docs) == [f.name for f in dataclasses.fields(TrainConfig)]  # every field documented, in order
    assert docs["gamma"] == "Discount factor."
    assert docs["sensing"].startswith("``perfect``, ``vicon`` (motion-capture noise")
    assert "\n" in docs["sensing"] and "    " not in docs["sensing"]  # indentation of the source removed


def test_plain_drops_markup_for_the_terminal():
    doc = "A :class:`~marlander_lite.task.TaskConfig`, :meth:`~a.Sensing.noisy`, :data:`X.Y` or ``pointmass``.\n  Two"
    assert plain(doc) == "A TaskConfig, Sensing.noisy, X.Y or pointmass. Two"


# ---------------------------------------------------------------------------- train


def test_every_train_config_field_is_an_option_with_its_docstring(capsys):
    text = help_of(capsys, ["train", "--help"])
    for field in dataclasses.fields(TrainConfig):
        flag = f"--{field.name.replace('_', '-')}"
        assert squeezed(plain(field_docs(TrainConfig)[field.name])) in entry(text, flag), field.name
    task_docs = field_docs(TaskConfig)
    for field in dataclasses.fields(TaskConfig):
        if field.name != "num_drones":  # TrainConfig.num_drones sets it
            flag = f"--task.{field.name.replace('_', '-')}"
            assert squeezed(plain(task_docs[field.name])) in entry(text, flag), field.name
    assert "--dynamics.family.max-tilt-deg" in text and "--dynamics.randomization" in text


def test_the_help_shows_the_chosen_presets_values(capsys):
    quick = help_of(capsys, ["train", "--help"])
    paper = help_of(capsys, ["train", "--preset", "paper", "--help"])
    assert entry(quick, "--net-arch").endswith("(default:128128)")
    assert entry(paper, "--net-arch").endswith("(default:512512256128)")
    assert entry(paper, "--total-steps").endswith("(default:20000000)")
    assert entry(quick, "--task.landing-tolerance").endswith("(default:0.03)")  # the preset's training aid
    assert entry(quick, "--task.max-speed").endswith("(default:3.0)")  # not in the preset: TaskConfig's
    assert entry(quick, "--target-kl").endswith("(default:none)")


@pytest.mark.parametrize("preset", list(PRESETS))
def test_no_option_leaves_the_preset_unchanged(preset):
    args = build_parser().parse_args(["train", "--preset", preset])
    assert args.config_options.apply(get_preset(preset), args) == get_preset(preset)


def test_train_trains_the_preset_when_no_field_is_given(no_training, tmp_path):
    assert main(["train", "--out", str(tmp_path / "run"), "--no-progress"]) == 0
    assert no_training == [get_preset("quick-cpu")]


def test_options_change_only_their_fields_and_dicts_are_merged(no_training, tmp_path):
    argv = ["train", "--preset", "moving", "--out", str(tmp_path / "run"), "--learning-rate", "1e-4"]
    argv += ["--env", "pointmass", "--steps", "5000", "--net-arch", "64", "32", "--no-normalize-rewards"]
    argv += ["--platform-speed", "0.2", "--critic-arch", "none", "--task.landing-tolerance", "none"]
    argv += ["--task.episode-seconds", "12", "--dynamics.family.max-tilt-deg", "20", "30"]
    assert main(argv) == 0
    preset = get_preset("moving")
    family = {**preset.dynamics["family"], "max_tilt_deg": (20.0, 30.0)}
    expected = dataclasses.replace(
        preset,
        learning_rate=1e-4,
        total_steps=5000,
        net_arch=(64, 32),
        normalize_rewards=False,
        platform_speed=0.2,
        critic_arch=None,
        task={**preset.task, "landing_tolerance": None, "episode_seconds": 12.0},
        dynamics={**preset.dynamics, "family": family},
    )
    assert no_training == [expected]


def test_a_json_dict_replaces_the_presets_and_dotted_keys_apply_on_top(no_training, tmp_path):
    argv = ["train", "--out", str(tmp_path / "run"), "--task", '{"alpha": 5}', "--task.beta", "-0.1"]
    argv += ["--dynamics", "{}", "--dynamics.max-tilt-deg", "25"]
    assert main(argv) == 0
    assert no_training[0].task == {"alpha": 5, "beta": -0.1}
    assert no_training[0].dynamics == {"max_tilt_deg": 25.0}


def test_a_field_set_on_the_command_line_is_in_the_saved_config(tmp_path):
    run = tmp_path / "run"
    argv = ["train", "--out", str(run), "--no-progress", "--total-steps", "2048", "--num-envs", "16"]
    argv += ["--n-steps", "128", "--batch-size", "256", "--net-arch", "16", "16", "--torch-threads", "1"]
    argv += ["--checkpoint-every", "0", "--learning-rate", "1e-4", "--gamma", "0.98"]
    argv += ["--task.landing-tolerance", "0.02", "--dynamics.family.latency-s", "0", "0.03"]
    assert main(argv) == 0
    preset = get_preset("quick-cpu")
    expected = preset.replace(
        total_steps=2048,
        num_envs=16,
        n_steps=128,
        batch_size=256,
        net_arch=(16, 16),
        torch_threads=1,
        checkpoint_every=0,
        learning_rate=1e-4,
        gamma=0.98,
        task={**preset.task, "landing_tolerance": 0.02},
        dynamics={"family": {**preset.dynamics["family"], "latency_s": [0.0, 0.03]}},
    )
    saved = json.loads((run / "config.json").read_text())["train"]
    assert saved == json.loads(json.dumps(expected.to_dict()))


@pytest.mark.parametrize(
    ("argv", "needles"),
    [
        (["--learning-rate", "fast"], ["argument --learning-rate: expected a number, got 'fast'"]),
        (["--lr-schedule", "cosine"], ["argument --lr-schedule", "allowed: constant, linear"]),
        (["--env", "mujoco"], ["argument --env", "allowed: pointmass, crazyflie"]),
        (["--net-arch", "64", "x"], ["argument --net-arch: expected one or more integers"]),
        (["--platform-speed", "1", "2", "3"], ["--platform-speed", "a number, 2 numbers or none"]),
        (["--num-envs", "0"], ["argument --num-envs", "positive integer"]),
        (["--normalize-rewards", "yes"], ["unrecognized arguments: yes"]),
        (["--learning-rte", "1e-4"], ["--learning-rte: did you mean --learning-rate?"]),
        (["--task.landing-tolrance", "0.02"], ["--task.landing-tolrance", "landing-tolerance, training-"]),
        (["--task", "[1]"], ["argument --task: expected a JSON object of TaskConfig fields"]),
        (["--task", '{"nope": 1}'], ["argument --task: unknown TaskConfig field(s) ['nope']; allowed: max_speed"]),
        (["--gamma", "1.5"], ["gamma and gae_lambda must be in (0, 1]"]),
        (["--env", "crazyflie"], ["point-mass simulator only", "Add --dynamics '{}'"]),
        (["--init-from", "RUN", "--num-drones", "3"], ["--init-from keeps", "drop --num-drones"]),
    ],
)
def test_a_wrong_value_or_unknown_field_is_one_line(capsys, tmp_path, monkeypatch, no_training, argv, needles):
    monkeypatch.chdir(tmp_path)
    fails(capsys, ["train", "--out", "run", *argv], *needles)
    assert list(tmp_path.iterdir()) == [] and no_training == []  # nothing written, train() never reached


# ---------------------------------------------------------------------------- evaluate


def test_evaluate_passes_its_options_and_only_those_given(capsys, monkeypatch):
    calls = []

    def record(path, **kwargs):
        calls.append(kwargs)
        return "a summary"

    monkeypatch.setattr(evaluation, "evaluate_policy_file", record)
    assert main(["evaluate", str(POLICY)]) == 0
    defaults = {"simulator": "pointmass", "episodes": 200, "seed": 12345, "platform": "static-floor"}
    assert calls[0] == {**defaults, "platform_speed": None, "sensing": "perfect"}
    argv = ["evaluate", str(POLICY), "--env", "crazyflie", "--controller", "firmware", "--platform-speed", "0.1", "0.3"]
    assert main([*argv, "--task.episode-seconds", "20", "--eval-seed", "3"]) == 0
    assert calls[1]["controller"] == "firmware" and calls[1]["platform_speed"] == (0.1, 0.3)
    assert calls[1]["task"] == {"episode_seconds": 20.0} and calls[1]["seed"] == 3
    fails(capsys, ["evaluate", str(POLICY), "--controller", "firmware"], "--controller", "--env crazyflie")
    text = help_of(capsys, ["evaluate", "--help"])
    assert entry(text, "--task.landing-tolerance").endswith("(default:thepolicy's,trainingaidsoff)")


# ---------------------------------------------------------------------------- reproduce


def test_every_protocol_field_is_an_option_with_its_docstring(capsys):
    text = help_of(capsys, ["reproduce", "--help"])
    flags = {"time_limit_s": "--time-limit"}
    for field in dataclasses.fields(ProtocolConfig):
        if field.name == "policy_paths":  # --marlander-policy, --single-agent-policy, --marlander-plus-policy
            continue
        if field.name == "apf":
            for gain in dataclasses.fields(APFConfig):
                doc = plain(field_docs(APFConfig)[gain.name])
                assert squeezed(doc) in entry(text, f"--apf.{gain.name.replace('_', '-')}")
            continue
        flag = flags.get(field.name, f"--{field.name.replace('_', '-')}")
        assert squeezed(plain(field_docs(ProtocolConfig)[field.name])) in entry(text, flag), field.name


def test_reproduce_defaults_and_recorded_command_are_unchanged():
    args = build_parser().parse_args(["reproduce"])
    assert config_from_args(args) == ProtocolConfig()
    record = json.loads((ROOT / "data" / "results" / "pointmass" / "run.json").read_text())
    shipped = ProtocolConfig(controllers=tuple(record["config"]["controllers"]))
    assert command_line(shipped, Path("data/results/pointmass")) == record["command"]


def test_a_changed_protocol_repeats_through_its_recorded_command():
    argv = ["reproduce", "--apf.k-p", "2", "--num-drones", "3", "--block-size", "5", "--time-limit-s", "12"]
    config = config_from_args(build_parser().parse_args([*argv, "--controllers", "baseline", "--seed", "4"]))
    assert config.apf == dataclasses.replace(APFConfig(), k_p=2.0)
    assert (config.num_drones, config.block_size, config.time_limit_s, config.seed) == (3, 5, 12.0, 4)
    assert changed_options(config, ProtocolConfig(), skip=("controllers", "seed", "time_limit_s")) == [
        "--num-drones",
        "3",
        "--apf.k-p",
        "2.0",
        "--block-size",
        "5",
    ]
    words = command_line(config, Path("runs/x")).split()[1:]
    assert config_from_args(build_parser().parse_args(words)) == config


def test_reproduce_errors_name_the_option(capsys):
    fails(capsys, ["reproduce", "--apf.k-p", "x"], "argument --apf.k-p: expected a number, got 'x'")
    fails(capsys, ["reproduce", "--apf.kp", "1"], "--apf.kp", "k-p, k-i, k-d")
    fails(capsys, ["reproduce", "--controllers", "pid"], "--controllers", "unknown controller(s) 'pid'")
    fails(capsys, ["reproduce", "--workers", "0"], "argument --workers", "positive integer")
