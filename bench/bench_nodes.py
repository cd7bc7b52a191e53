"""Benchmark the node pipeline of ``microball experiment``: CPU share per node, fastest speed.

Run: ``python bench/bench_nodes.py [--duration S] [--ladder-duration S] [--speeds 1,1.5,...]``.
Prints plain Markdown tables; asserts nothing. Takes about two and a half minutes on 2 cores.

1. CPU share of each node at 30 fps in real time (speed 1.0) on the 'paper' scenario: the
   five node processes are started as ``microball experiment`` starts them, and each one's
   CPU time (utime + stime of /proc/<pid>/stat, all threads) is sampled when the bench's first
   frame reaches the monitor and again when the last frame has been tracked; the share is that
   CPU time over the same wall interval. What the estimator and identifier still do after the
   last frame (their queues draining) is shown in its own column, not in the share. The
   bench_simulator is the rig's stand-in (servo, bearing and synthetic camera); the pipeline
   total is given with and without it, and the synthetic camera's rendering cost is measured
   in this process (RigStepper, render_frame timed apart) for comparison.
2. Fastest speed factor at which the simulated experiment still drops nothing: a short run at
   each speed of a ladder. No drops = the bench published every frame of the duration, each
   was tracked, the estimator emitted as many windows as at speed 1, and the bench achieved the
   requested speed (simulated seconds over wall seconds between the first and last frame
   reaching the monitor, within 5 %).

Every run gets its own ROS_DOMAIN_ID (150 + pid % 50 + run number; the tests use 1..100) and
localhost-only discovery, so it never sees a test run or another benchmark.
"""

import argparse
import math
import os
import shutil
import signal
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import rclpy  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402

from microball_ros.app.experiment import (  # noqa: E402
    _READY,
    NODES,
    NodeCrashed,
    NodeProcesses,
    _Monitor,
    node_parameters,
)
from microball_ros.core import bench, rig  # noqa: E402

SCENARIO = 'paper'
CLOCK_TICK = os.sysconf('SC_CLK_TCK')
QUIET_PERIOD = 3.0  # wall s without any message: the estimator and identifier have drained
SPEED_TOLERANCE = 0.05  # achieved speed may fall this far (relative) short of the requested


def _log(message):
    print(f'[bench_nodes] {message}', file=sys.stderr, flush=True)


def cpu_seconds(pid):
    """Return utime + stime of a process (all its threads), s; nan if it has gone."""
    try:
        with open(f'/proc/{pid}/stat') as handle:
            stat = handle.read()
    except OSError:
        return math.nan
    fields = stat[stat.rindex(')') + 2:].split()  # fields[0] is field 3 (state)
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICK


class _TimedMonitor(_Monitor):
    """The experiment's monitor, also noting when the first frame and last tracked arrive."""

    def __init__(self, context):
        super().__init__(context)
        self.first_frame_time = None
        self.last_frame_time = None
        self.last_tracked_time = None

    def _on_frame(self, msg):
        self.last_frame_time = time.monotonic()
        if self.first_frame_time is None:
            self.first_frame_time = self.last_frame_time
        super()._on_frame(msg)

    def _on_tracked(self, msg):
        self.last_tracked_time = time.monotonic()
        super()._on_tracked(msg)


class _Run:
    """What one run measured: counts, wall times and CPU samples per node."""

    def __init__(self, speed, duration, expected_frames, fps):
        self.speed = speed
        self.duration = duration
        self.expected_frames = expected_frames
        self.fps = fps
        self.frames = self.tracked = self.windows = 0
        self.wall = math.nan  # first frame -> last tracked frame, s
        self.bench_wall = math.nan  # first frame -> last frame, s
        self.cpu_start = self.cpu_last = self.cpu_end = None  # name -> CPU s
        self.error = None

    @property
    def achieved_speed(self):
        """Return simulated seconds per wall second between the first and last frame."""
        if self.frames < 2 or not self.bench_wall > 0:
            return math.nan
        return (self.frames - 1) / self.fps / self.bench_wall


def _sample(pids):
    return {name: cpu_seconds(pid) for name, pid in pids.items()}


def run_nodes(run_number, duration, speed, scenario_name=SCENARIO):
    """Run the five nodes once (as run_experiment does) and return the _Run measurements."""
    os.environ['ROS_DOMAIN_ID'] = str(150 + os.getpid() % 50 + run_number)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    fps = rig.camera_for(bench.get_scenario(scenario_name)).fps
    result = _Run(speed, duration, math.floor(duration * fps + 1e-9), fps)
    log_dir = tempfile.mkdtemp(prefix='microball-bench-nodes-')
    context = rclpy.Context()
    rclpy.init(context=context)
    monitor = _TimedMonitor(context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(monitor.node)
    processes = NodeProcesses(node_parameters(scenario_name, duration, speed), log_dir)
    node = monitor.node
    pids = {}
    wall_limit = time.monotonic() + 30.0 + 3.0 * duration / speed

    def spin_until(condition, what):
        while not condition():
            executor.spin_once(timeout_sec=0.05)
            processes.check()
            if time.monotonic() > wall_limit:
                raise NodeCrashed(f'timed out waiting for {what}; node logs in {log_dir}')

    try:
        for name in NODES:
            if name != 'bench_simulator':
                processes.start(name)
        spin_until(lambda: all(node.count_subscribers(topic) >= count
                               for topic, count in _READY.items()), 'the nodes to connect')
        processes.start('bench_simulator')
        pids = {name: proc.pid for name, (proc, _) in processes.procs.items()}
        pids['monitor (this script)'] = os.getpid()
        spin_until(lambda: monitor.frames >= 1, 'the first frame')
        result.cpu_start = _sample(pids)
        spin_until(lambda: min(monitor.frames, monitor.tracked) >= result.expected_frames,
                   'every frame to be tracked')
        result.cpu_last = _sample(pids)
        result.wall = monitor.last_tracked_time - monitor.first_frame_time
        spin_until(lambda: time.monotonic() - monitor.last_change > QUIET_PERIOD,
                   'the estimator and identifier to drain')
        result.cpu_end = _sample(pids)
    except NodeCrashed as error:
        result.error = str(error)
    finally:
        result.frames, result.tracked = monitor.frames, monitor.tracked
        if monitor.frames >= 2:
            result.bench_wall = monitor.last_frame_time - monitor.first_frame_time
        result.windows = len(monitor.windows)
        processes.stop()
        executor.shutdown()
        monitor.node.destroy_node()
        if context.ok():
            rclpy.shutdown(context=context)
    if result.error is None:
        shutil.rmtree(log_dir, ignore_errors=True)  # kept (and named) when a run fails
    return result


def render_share(frames=45, warmup=15, scenario_name=SCENARIO):
    """Return (rig step CPU s per frame, of which render_frame) measured in this process."""
    scenario = bench.get_scenario(scenario_name)
    stepper = rig.RigStepper(scenario)
    stepper.command(2 * math.pi * scenario.frequency, 1.0)
    render = stepper.camera.render_frame
    spent = [0.0]

    def timed_render(*args, **kwargs):
        start = time.process_time()
        try:
            return render(*args, **kwargs)
        finally:
            spent[0] += time.process_time() - start

    stepper.camera.render_frame = timed_render
    for _ in range(warmup):
        stepper.next_frame()
    spent[0] = 0.0
    start = time.process_time()
    for _ in range(frames - warmup):
        stepper.next_frame()
    total = time.process_time() - start
    return total / (frames - warmup), spent[0] / (frames - warmup)


def _pct(value):
    return 'n/a' if not math.isfinite(value) else f'{100 * value:.1f} %'


def cpu_table(run):
    """Return the Markdown lines of table 1 for a real-time run."""
    if run.error or run.cpu_end is None:
        return [f'run failed: {run.error}']
    lines = ['| node | CPU s | share of one core | ratio to goal (1 core) '
             '| CPU s after last frame |',
             '|---|---:|---:|---:|---:|']
    used = {name: run.cpu_last[name] - run.cpu_start[name] for name in run.cpu_start}
    drain = {name: run.cpu_end[name] - run.cpu_last[name] for name in run.cpu_start}

    def row(label, cpu, tail):
        share = cpu / run.wall
        return f'| {label} | {cpu:.2f} | {_pct(share)} | {share:.2f} | {tail:.2f} |'

    for name in NODES:
        lines.append(row(name, used[name], drain[name]))
    total = sum(used[name] for name in NODES)
    total_drain = sum(drain[name] for name in NODES)
    lines.append(row('**pipeline total (5 nodes)**', total, total_drain))
    rest = [name for name in NODES if name != 'bench_simulator']
    lines.append(row('pipeline without bench_simulator', sum(used[n] for n in rest),
                     sum(drain[n] for n in rest)))
    name = 'monitor (this script)'
    lines.append(row(f'{name}, not counted', used[name], drain[name]))
    return lines


def ladder_table(runs):
    """Return the Markdown lines of table 2 and the fastest drop-free speed (or None)."""
    reference = next((r.windows for r in runs if r.speed == 1.0 and not r.error), None)
    lines = ['| requested speed | achieved speed | frames published | frames tracked '
             '| windows | bench_simulator CPU | verdict |',
             '|---:|---:|---:|---:|---:|---:|---|']
    fastest = None
    for run in runs:
        problems = []
        if run.error:
            problems.append('timed out' if 'timed out' in run.error else 'node crashed')
        if run.frames != run.expected_frames:
            problems.append(f'bench published {run.frames} of {run.expected_frames}')
        if run.tracked != run.frames:
            problems.append(f'{run.frames - run.tracked} frames not tracked')
        if reference is not None and run.windows != reference:
            problems.append(f'{run.windows} windows, {reference} at speed 1')
        drops = bool(problems)
        achieved = run.achieved_speed
        if not achieved >= (1.0 - SPEED_TOLERANCE) * run.speed:
            problems.append('bench slower than requested')
        verdict = 'no drops' if not problems else (
            ('DROPS: ' if drops else 'no drops, but ') + '; '.join(problems))
        if not problems:
            fastest = run.speed
        bench_cpu = math.nan
        if run.cpu_last is not None:
            bench_cpu = (run.cpu_last['bench_simulator']
                         - run.cpu_start['bench_simulator']) / run.wall
        lines.append(f'| {run.speed:g} | {achieved:.2f} | {run.frames} | {run.tracked} '
                     f'| {run.windows} | {_pct(bench_cpu)} | {verdict} |')
    return lines, fastest


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def _loadavg():
    return ', '.join(f'{v:.2f}' for v in os.getloadavg())


def _positive_floats(text):
    values = [float(v) for v in text.split(',')]
    if not values or min(values) <= 0:
        raise argparse.ArgumentTypeError('expected positive numbers separated by commas')
    return values


def main():
    """Run the benchmark and print its tables."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--duration', type=float, default=30.0,
                        help='simulated seconds of the real-time CPU run (default 30)')
    parser.add_argument('--ladder-duration', type=float, default=10.0,
                        help='simulated seconds of each speed-ladder run (default 10)')
    parser.add_argument('--speeds', type=_positive_floats, default=[1.0, 1.25, 1.5, 2.0, 3.0, 4.0],
                        help='speed ladder, comma separated (default 1,1.25,1.5,2,3,4)')
    args = parser.parse_args()
    signal.signal(signal.SIGTERM, _interrupt)
    started = time.monotonic()
    load_start = _loadavg()
    fps = rig.camera_for(bench.get_scenario(SCENARIO)).fps
    try:
        _log(f'real-time run: {args.duration:g} simulated s at speed 1.0')
        realtime = run_nodes(0, args.duration, 1.0)
        _log(f'done in {time.monotonic() - started:.0f} s')
        step_cpu, render_cpu = render_share()
        ladder = []
        for number, speed in enumerate(args.speeds, start=1):
            _log(f'ladder: {args.ladder_duration:g} simulated s at speed {speed:g}')
            ladder.append(run_nodes(number, args.ladder_duration, speed))
            _log(f'done in {time.monotonic() - started:.0f} s')
    except KeyboardInterrupt:
        _log('interrupted; every node process has been stopped')
        return 130
    runtime = time.monotonic() - started

    print('# microball_ros node benchmark\n')
    print(f'{os.cpu_count()} CPUs; load average (1, 5, 15 min) at start: {load_start}; '
          f"RMW: {os.environ.get('RMW_IMPLEMENTATION', 'default (rmw_fastrtps_cpp)')}\n")
    print(f"## CPU per node: '{SCENARIO}' scenario, {fps:g} fps in real time (speed 1.0)\n")
    print(f'{realtime.tracked} frames tracked over {realtime.wall:.2f} wall s (first frame to '
          'last tracked; share = CPU s / that wall time).\n')
    print('\n'.join(cpu_table(realtime)))
    bench_share = math.nan
    if realtime.cpu_end is not None:
        pid_cpu = realtime.cpu_last['bench_simulator'] - realtime.cpu_start['bench_simulator']
        bench_share = pid_cpu / realtime.wall
    total_share = math.nan
    if realtime.cpu_end is not None:
        total_share = sum(realtime.cpu_last[n] - realtime.cpu_start[n]
                          for n in NODES) / realtime.wall
    print(f'\nThe bench_simulator is the rig stand-in, not part of a real pipeline. Measured '
          f"in this process (RigStepper.next_frame, {fps:g} fps): the synthetic camera's "
          f'render_frame takes {1e3 * render_cpu:.1f} ms CPU per frame = '
          f'{_pct(render_cpu * fps)} of one core, the whole rig step (bearing integration + '
          f"rendering) {1e3 * step_cpu:.1f} ms = {_pct(step_cpu * fps)}, of the node's "
          f'{_pct(bench_share)}; the rest is building and publishing the 720 x 480 image '
          f'messages. Pipeline total minus the rendering alone: '
          f'{_pct(total_share - render_cpu * fps)}.\n')
    print(f'## Fastest drop-free speed: {args.ladder_duration:g} simulated s per run '
          f'({math.floor(args.ladder_duration * fps + 1e-9)} frames)\n')
    lines, fastest = ladder_table(ladder)
    print('\n'.join(lines))
    print(f'\nFastest speed with no drops at the requested rate: '
          f"{'none' if fastest is None else f'{fastest:g}x'}.\n")
    print(f'Load average at end: {_loadavg()}; benchmark runtime {runtime:.0f} s. The machine '
          'is shared and noisy: other jobs inflate wall times and CPU shares, so treat the '
          'figures as +-10-20 % and compare runs made under similar load.')
    for run in [realtime, *ladder]:
        if run.error:
            print(f'\nspeed {run.speed:g}: {run.error}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
