"""`microball experiment`: every node a separate process over DDS, end to end."""

import os
import select
import signal
import subprocess
import sys
import tempfile
import time

import pytest

from microball_ros.app.experiment import run_experiment


def _run(scenario, duration=20.0, speed=1.5):
    return run_experiment(scenario, duration, speed, progress=lambda line: None)


def test_paper_experiment_recovers_the_bench_model_and_calls_it_memoryless(tmp_path,
                                                                            monkeypatch):
    monkeypatch.setattr(tempfile, 'tempdir', str(tmp_path))
    monitor = _run('paper')
    # a run that succeeds leaves no node logs behind (the domain's lock file may stay)
    assert list(tmp_path.glob('microball-experiment-*')) == []
    assert monitor.frames == monitor.tracked == 600
    assert len(monitor.windows) >= 10
    assert all(memoryless for _, _, memoryless in monitor.windows)
    model = monitor.models[-1]
    assert model.name == 'langevin'
    assert model.a_ci95[0] <= 1.2 <= model.a_ci95[1]
    assert model.alpha_ci95[0] <= 110.0 <= model.alpha_ci95[1]
    assert model.a == pytest.approx(1.2, rel=0.05)
    assert model.alpha == pytest.approx(110.0, rel=0.05)
    assert model.slider_amplitude_simulated == pytest.approx(model.slider_amplitude_measured,
                                                             rel=0.01)


def test_lagged_friction_is_called_hysteretic():
    monitor = _run('lagged')
    assert len(monitor.windows) >= 10
    assert not any(memoryless for _, _, memoryless in monitor.windows)
    # A 35 ms lag at 2.95 Hz moves the phase by about atan(w tau) = 0.57 rad from pi.
    assert all(2.3 < phase < 2.8 for phase, _, _ in monitor.windows)


def _children(pid):
    path = f'/proc/{pid}/task/{pid}/children'
    with open(path) as handle:
        return [int(child) for child in handle.read().split()]


def _command_line(pid):
    with open(f'/proc/{pid}/cmdline', 'rb') as handle:
        return handle.read().replace(b'\0', b' ').decode()


def _start_cli():
    cli = subprocess.Popen([sys.executable, '-m', 'microball_ros.cli', 'experiment',
                            '--duration', '60', '--speed', '1.5'],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    for line in cli.stderr:
        if 'the bench is running' in line:
            break
    children = _children(cli.pid)
    assert len(children) == 5
    return cli, children


def _assert_all_gone(children, timeout=10.0):
    """Wait (pidfd: no polling loop) until every child process has exited."""
    deadline = time.monotonic() + timeout
    for pid in children:
        try:
            fd = os.pidfd_open(pid)
        except ProcessLookupError:
            continue  # already gone and reaped
        try:
            ready, _, _ = select.select([fd], [], [], max(0.0, deadline - time.monotonic()))
            assert ready or _state(pid) in ('Z', 'gone'), f'node process {pid} left running'
        finally:
            os.close(fd)


def test_a_crashing_node_is_named_and_no_process_is_left_behind():
    cli, children = _start_cli()
    try:
        estimator = next(pid for pid in children
                         if 'three_stage_estimator' in _command_line(pid))
        os.kill(estimator, signal.SIGKILL)
        _, err = cli.communicate(timeout=60)
    finally:
        if cli.poll() is None:
            cli.kill()
    assert cli.returncode == 1
    assert 'node three_stage_estimator exited with code -9' in err
    log = err.split('its log: ')[1].split()[0]
    assert os.path.isfile(log)  # a failed run keeps the node logs its error names
    _assert_all_gone(children)


def test_ctrl_c_stops_every_node_and_exits_130():
    cli, children = _start_cli()
    try:
        cli.send_signal(signal.SIGINT)
        _, err = cli.communicate(timeout=60)
    finally:
        if cli.poll() is None:
            cli.kill()
    assert cli.returncode == 130
    assert 'interrupted' in err and 'Traceback' not in err
    _assert_all_gone(children)


def _state(pid):
    try:
        with open(f'/proc/{pid}/stat') as handle:
            return handle.read().rsplit(')', 1)[1].split()[0]
    except FileNotFoundError:
        return 'gone'
