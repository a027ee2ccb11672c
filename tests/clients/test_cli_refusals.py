"""Options a command must refuse before it starts anything (exit 2, one line naming the option):
values that would crash it later, make it wait for ever, or be found only after the work."""
from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from fpscan.clients.cli import main
from fpscan.service.settings import LOG_LEVELS, Settings
from tests.waits import HANG_S


def exit_code(argv, capsys):
    with pytest.raises(SystemExit) as stop:
        raise SystemExit(main(argv))
    return stop.value.code, capsys.readouterr().err


@pytest.mark.parametrize("flags, fragment", [
    (["--log-level", "bogus"], "log level must be one of critical, error, warning, info, debug, trace"),
    (["--memory-limit", "nan"], "--memory-limit must be a finite number of GiB > 0, got nan"),
])
def test_serve_refuses_its_options_in_one_line(flags, fragment, tmp_path):
    # in a process of its own: `fpscan serve` restarts itself in place (its allocator) before it reads options
    env = {**os.environ, "FPSCAN_TOKEN": "0123456789abcdef" * 4}
    done = subprocess.run([sys.executable, "-m", "fpscan", "serve", "--port", "0", "--data-dir", str(tmp_path / "srv"),
                           *flags], env=env, capture_output=True, text=True, timeout=HANG_S)
    assert done.returncode == 2 and fragment in done.stderr, done.stderr
    assert "Traceback" not in done.stderr


def test_a_log_level_uvicorn_does_not_know_is_refused_by_the_settings():
    with pytest.raises(ValueError, match="log level must be one of"):
        Settings(log_level="verbose")
    assert [Settings(log_level=level.upper()).log_level for level in LOG_LEVELS] == list(LOG_LEVELS)


@pytest.mark.parametrize("argv", [
    ["scan", "--device", "/dev/null", "--plan", "p.json", "--out", "s.h5", "--timeout", "nan"],
    ["scan", "--device", "/dev/null", "--plan", "p.json", "--out", "s.h5", "--timeout", "inf"],
    ["scan", "--device", "/dev/null", "--plan", "p.json", "--out", "s.h5", "--timeout", "0"],
    ["jobs", "wait", "abc", "--server", "http://127.0.0.1:9", "--timeout", "-1"],
    ["jobs", "wait", "abc", "--server", "http://127.0.0.1:9", "--timeout", "nan"],
])
def test_a_time_limit_is_a_finite_number_of_seconds_above_zero(argv, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, err = exit_code(argv, capsys)
    assert code == 2 and "--timeout must be a finite number of seconds > 0" in err, err


@pytest.mark.parametrize("speed", ["0", "-1500", "1e9", "1.5"])
def test_the_simulator_keeps_the_speed_limits_even_with_force(speed, capsys):
    code, err = exit_code(["sim", "--prf", "0", f"--sound-speed={speed}", "--force"], capsys)
    assert code == 2 and "within 100-10000 m/s even with force" in err, err


def test_the_simulator_refuses_a_record_it_cannot_write_before_it_starts(capsys):
    code, err = exit_code(["sim", "--prf", "0", "--record", "/proc/forbidden/truth.h5"], capsys)
    assert code == 2 and "--record /proc/forbidden/truth.h5: cannot write in /proc/forbidden" in err, err


@pytest.mark.parametrize("argv", [["sim", "--seed", "-1"], ["demo", "--seed", "-1", "--no-dense", "-q"],
                                  ["sim", "--seed", "x"]])
def test_a_seed_is_a_non_negative_integer(argv, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, err = exit_code(argv, capsys)
    assert code == 2 and "a seed is an integer >= 0" in err, err
    assert not (tmp_path / "demo-output").exists()


@pytest.mark.parametrize("flags, fragment", [
    (["--threshold", "-1"], "threshold must lie in [0, 1)"),
    (["--threshold", "nan"], "threshold must lie in [0, 1)"),
    (["--fluence", "1", "-1"], "fluence must be finite and > 0"),
    (["--fluence", "1", "2", "3"], "fluence has 3 values for 2 wavelengths"),
])
def test_unmixing_options_are_refused_before_any_wavelength_is_reconstructed(flags, fragment, capsys, tmp_path):
    a, b = tmp_path / "a.npy", tmp_path / "b.npy"
    for p in (a, b):
        np.save(p, np.zeros((16, 4, 4), dtype=np.float32))
    progress = []
    from fpscan.service.pipeline import run_file

    unmix = {"threshold": float(flags[1]) if flags[0] == "--threshold" else 0.1,
             "fluence": [float(v) for v in flags[1:]] if flags[0] == "--fluence" else None}
    with pytest.raises(ValueError, match=fragment.replace("[", r"\[").replace(")", r"\)")):
        run_file([a, b], tmp_path / "u", "ner", wavelengths=[7.5e-7, 8.5e-7], unmix=unmix,
                 load={"dt": 2e-8, "dx": 1e-4}, progress=lambda f, s: progress.append(s))
    assert not any(s.startswith("reconstructing") for s in progress), progress
    code, err = exit_code(["unmix", str(a), str(b), "--wavelengths", "750nm", "850nm", "--dt", "20ns", "--dx", "100um",
                           "-q", "--out", str(tmp_path / "cli")] + flags, capsys)
    assert code == 2 and fragment in err, err
    assert not (tmp_path / "cli").exists()


def test_a_child_that_exits_before_its_first_line_is_reported_as_such(tmp_path):
    from fpscan.clients.processes import Process

    child = Process([sys.executable, "-c", "import sys; sys.exit('fpscan sim: error: refused')"],
                    log_path=tmp_path / "child.log", stdout_pipe=True)
    try:
        with pytest.raises(RuntimeError) as caught:
            child.first_line(timeout=HANG_S)
    finally:
        child.stop()
    message = str(caught.value)
    assert "exited (status 1) before its first line" in message and "within" not in message, message
    assert message.split(":\n", 1)[1].count("fpscan sim: error: refused") == 1, message  # its stderr, once


def test_export_of_a_result_folder_names_the_volume_inside(tmp_path, capsys):
    folder = tmp_path / "scan-nedner"
    folder.mkdir()
    (folder / "volume.h5").write_bytes(b"")
    code, err = exit_code(["export", str(folder)], capsys)
    assert code == 2 and f"is a folder, not a file: give its volume, fpscan export {folder / 'volume.h5'}" in err, err
