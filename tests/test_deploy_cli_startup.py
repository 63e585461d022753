"""Ctrl-C during the ``marlander`` command's start-up: one line ``Interrupted.``, exit status 130, no traceback.

About 2 s of the command's start-up is importing ``marlander_lite`` (gymnasium, pettingzoo,
Stable-Baselines3 and torch) before ``cli.main`` runs; ``marlander_lite/__init__.py`` handles a
Ctrl-C there when the program is the ``marlander`` command, and only then.
"""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

MARLANDER = Path(sys.executable).with_name("marlander")
pytestmark = pytest.mark.skipif(
    not MARLANDER.exists() or os.name != "posix", reason="needs the installed marlander script on POSIX"
)


def interrupted_run(args: list[str], delay_s: float) -> subprocess.CompletedProcess:
    """Run ``args``, send SIGINT after ``delay_s`` (unless it has finished), and wait for it."""
    proc = subprocess.Popen(
        args,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        # a test run in the background may have SIGINT ignored, and children inherit that: restore the default
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    time.sleep(delay_s)
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    return subprocess.CompletedProcess(args, proc.returncode, out, err)


def test_ctrl_c_while_marlander_starts_up_prints_one_line_and_exits_130():
    codes = []
    for delay_s in (0.3, 0.8, 1.3):  # early, during torch, later in the imports
        run = interrupted_run([str(MARLANDER), "--help"], delay_s)
        assert "Traceback" not in run.stderr, run.stderr
        if run.returncode == 0:  # it had finished already: a clean exit
            assert "usage: marlander" in run.stdout
        else:
            assert run.returncode == 130, (run.returncode, run.stderr)
            assert run.stderr.strip() == "Interrupted.", run.stderr
        codes.append(run.returncode)
    assert 130 in codes, codes  # at least one Ctrl-C landed in the start-up


def test_the_start_up_handler_exits_even_from_inside_an_import_machinery_callback():
    # CI once sent the Ctrl-C while importlib ran the weakref callback of a module lock: a SystemExit raised there is
    # printed as "Exception ignored" with a traceback and the start-up goes on. Run the handler from such a callback.
    code = (
        "import signal, weakref\n"
        "import marlander_lite\n"
        "class Lock: pass\n"
        "lock = Lock()\n"
        "ref = weakref.ref(lock, lambda _: marlander_lite._interrupted_during_start_up(signal.SIGINT, None))\n"
        "del lock\n"
        "print('went on')\n"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert run.returncode == 130, (run.returncode, run.stderr)
    assert run.stderr.strip().splitlines()[-1] == "Interrupted." and "Traceback" not in run.stderr, run.stderr
    assert "went on" not in run.stdout


def test_a_library_user_still_gets_the_keyboard_interrupt():
    # any other program that imports marlander_lite sees the KeyboardInterrupt as usual (not a silent exit)
    code = "import marlander_lite"
    run = interrupted_run([sys.executable, "-c", code], 0.3)
    if run.returncode != 0:
        assert "KeyboardInterrupt" in run.stderr, run.stderr
        assert run.returncode in (-signal.SIGINT, 128 + signal.SIGINT, 1), run.returncode


def test_importing_the_package_still_registers_the_gym_ids():
    import gymnasium as gym

    import marlander_lite

    env = gym.make(marlander_lite.ENV_IDS["pointmass"])
    try:
        obs, _ = env.reset(seed=0)
        assert obs is not None
    finally:
        env.close()


def run_python_with_default_sigint(code: str) -> subprocess.CompletedProcess[str]:
    """``python -c code`` with SIGINT at its default: a shell starts background jobs (a CI runner's, say) with it
    ignored, Python then installs no handler of its own, and the library rightly leaves it ignored."""
    return subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=60,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )


def test_ctrl_c_between_the_package_import_and_cli_main_is_quiet_too():
    """The start-up also imports ``marlander_lite.cli`` after the package; on a fast host a Ctrl-C 0.3 s in landed
    there, past the package's imports, and printed a traceback. The command's start-up handler holds until
    ``cli.main`` runs. The signal is sent at that point on purpose, not by timing."""
    code = (
        "import sys; sys.argv[0] = 'marlander'\n"
        "import os, signal, time, marlander_lite\n"
        "os.kill(os.getpid(), signal.SIGINT); time.sleep(2); print('not interrupted')\n"
    )
    run = run_python_with_default_sigint(code)
    assert (run.returncode, run.stderr.strip(), run.stdout) == (130, "Interrupted.", ""), run
    # Once cli.main runs, Python's own handler is back, and main turns the KeyboardInterrupt into the same line.
    code = (
        "import sys; sys.argv[0] = 'marlander'\n"
        "import os, signal, marlander_lite, marlander_lite.cli as cli\n"
        "cli.restore_interrupt_handler()\n"
        "assert signal.getsignal(signal.SIGINT) is signal.default_int_handler\n"
    )
    run = run_python_with_default_sigint(code)
    assert run.returncode == 0, run.stderr
