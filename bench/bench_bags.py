"""Benchmark the bags: recorder throughput, player rate and the analysis of an hour of positions.

Run: ``python bench/bench_bags.py [--analysis-duration S] [--skip-bag-analysis]``. Prints
plain Markdown tables; asserts nothing. The speed goals are the "Speed (bench/)" section of
issue 6. Takes about three minutes on 2 cores.

1. Recorder end to end: a publisher process publishes pre-serialized messages (reliable,
   the nodes' DATA_QOS) to a Recorder node spun in this process, as fast as the recorder keeps
   up: it never has more than a window of messages in flight beyond what the recorder has
   written (the recorder's count is shared through shared memory), so nothing can be dropped
   by design, and sent, recorded and the recorder's ``lost`` counts are compared. Small
   messages (TrackedPositions) and 720 x 480 mono8 frames (sensor_msgs/Image, rendered by the
   synthetic camera) at the highest rate, then frames paced at 30 fps. The same payloads are
   written in this process with the raw ``mcap.writer.Writer`` (zstd, 1 MiB chunks, like
   BagWriter) for the ours/raw ratio.
2. Pure write cost: BagWriter vs the raw mcap Writer on identical byte payloads, no DDS
   (best of 3 alternating repetitions, open to close including fsync).
3. Player: Player.play(lockstep=True) in a child process (with use_lockstep_profile() before
   rclpy.init, as ``microball play --lockstep`` does) to one subscriber in this process, and
   to one in another child process that loads the profile too (as ``microball reprocess``'s
   nodes do); then non-lock-step at the highest rate (rate 0: no pacing).
4. Analysis of an hour of 30 fps positions of the 'paper' scenario (108,000 samples) with
   analyze_record, from memory and from a bag written by BagWriter and read by load_positions,
   timed per stage, best of 3. Simulating the hour with bench.simulate takes about two
   minutes, so the record is built from a 20 s stretch of the noise-free simulation (a whole
   number of stator periods; the motion is periodic there up to a constant slider creep per
   tile, checked), plus the noise and drift drawn for the whole hour exactly as
   bench.simulate draws them; the construction is checked against bench.simulate on a
   shorter record (max difference shown).

Every DDS run gets its own ROS_DOMAIN_ID (206 + pid % 20 + run number; the tests use 1..100,
bench_nodes 150..206) and localhost-only discovery. Temporary bags and child processes are
removed on exit, also on Ctrl-C.
"""

import argparse
import contextlib
from dataclasses import replace
import io
import math
import multiprocessing
import os
import queue
import shutil
import signal
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from mcap.writer import CompressionType, Writer  # noqa: E402
import numpy as np  # noqa: E402
import rclpy  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402
from rclpy.signals import SignalHandlerOptions  # noqa: E402

from microball_ros.app import analysis  # noqa: E402
from microball_ros.core import bench, estimation, friction, rig  # noqa: E402
from microball_ros.core.records import PositionRecord  # noqa: E402
from microball_ros.io import conversions  # noqa: E402
from microball_ros.io.bags.schema import message_definition, qos_profiles_yaml  # noqa: E402
from microball_ros.io.bags.writer import BagWriter  # noqa: E402
from microball_ros.nodes.common import DATA_QOS  # noqa: E402

POSITIONS = '/tracking/positions'
POSITIONS_TYPE = 'microball_msgs/msg/TrackedPositions'
IMAGES = '/camera/image_raw'
IMAGE_TYPE = 'sensor_msgs/msg/Image'
SCENARIO = 'paper'
FPS = 30.0
CHUNK_SIZE = 1024 * 1024  # BagWriter's default
COMPRESSION = 'zstd'  # the recorder's default
RATIO_GOAL = 1.5
ANALYSIS_GOAL = 2.0  # s
TILE = 20.0  # s: 59 stator periods of 2.95 Hz and 600 frames of 30 fps
QUIET = 3.0  # s without a new message: the rest is not coming
MB = 1e6


def _log(message):
    print(f'[bench_bags] {message}', file=sys.stderr, flush=True)


def _loadavg():
    return ', '.join(f'{v:.2f}' for v in os.getloadavg())


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def _dds_env(run):
    """Return (and set here) the environment isolating DDS run number ``run``."""
    env = {'ROS_DOMAIN_ID': str(206 + os.getpid() % 20 + run),
           'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}
    os.environ.update(env)
    return env


def _init(context):
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)


def _child_signals():
    """In a child: leave Ctrl-C to the parent, turn its SIGTERM into a clean exit."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, lambda signum, frame: sys.exit(1))


# ---------------------------------------------------------------------------------------------
# Payloads
# ---------------------------------------------------------------------------------------------

def position_payloads(n=600):
    """Return n serialized TrackedPositions (distinct stamps and positions)."""
    return [bytes(serialize_message(conversions.tracked_positions(
        k / FPS, k, 1e-3 * math.sin(k / 3), 1.2e-3 * math.cos(k / 3), 0.9, 0.95)))
        for k in range(n)]


def frame_payloads(n=8, warmup=4):
    """Return n serialized 720 x 480 mono8 Images of the synthetic camera, rig running."""
    scenario = bench.get_scenario(SCENARIO)
    stepper = rig.RigStepper(scenario)
    stepper.command(2 * math.pi * scenario.frequency, 0.0)
    frames = [stepper.next_frame() for _ in range(warmup + n)][warmup:]
    return [bytes(serialize_message(conversions.image_message(f.image, f.stamp)))
            for f in frames]


# ---------------------------------------------------------------------------------------------
# Pure write cost
# ---------------------------------------------------------------------------------------------

def write_raw(path, topic, type_name, payloads, count):
    """Write count payloads with the raw mcap Writer (zstd, 1 MiB chunks); return wall s."""
    start = time.perf_counter()
    with open(path, 'xb') as handle:
        writer = Writer(handle, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD)
        writer.start(profile='ros2', library='bench_bags raw mcap')
        schema = writer.register_schema(name=type_name, encoding='ros2msg',
                                        data=message_definition(type_name).encode('utf-8'))
        channel = writer.register_channel(
            topic=topic, message_encoding='cdr', schema_id=schema,
            metadata={'offered_qos_profiles': qos_profiles_yaml([DATA_QOS])})
        period = int(1e9 / FPS)
        m = len(payloads)
        for k in range(count):
            writer.add_message(channel_id=channel, log_time=k * period, data=payloads[k % m],
                               publish_time=k * period, sequence=k + 1)
        writer.finish()
        handle.flush()
        os.fsync(handle.fileno())
    return time.perf_counter() - start


def write_ours(directory, topic, type_name, payloads, count):
    """Write count payloads with BagWriter (zstd, 1 MiB chunks); return wall s."""
    start = time.perf_counter()
    with BagWriter(directory, compression=COMPRESSION, chunk_size=CHUNK_SIZE) as bag:
        bag.add_topic(topic, type_name, qos_profiles_yaml([DATA_QOS]))
        period = int(1e9 / FPS)
        m = len(payloads)
        for k in range(count):
            bag.write(topic, payloads[k % m], k * period, k * period)
    return time.perf_counter() - start


def write_cost(workdir, label, topic, type_name, payloads, count, repeats=3):
    """Return best-of-repeats timings and file sizes of raw mcap vs BagWriter."""
    raw_times, our_times = [], []
    for r in range(repeats):
        raw_path = os.path.join(workdir, f'raw_{label}_{r}.mcap')
        our_dir = os.path.join(workdir, f'ours_{label}_{r}')
        raw_times.append(write_raw(raw_path, topic, type_name, payloads, count))
        our_times.append(write_ours(our_dir, topic, type_name, payloads, count))
        raw_size = os.path.getsize(raw_path)
        our_size = sum(os.path.getsize(os.path.join(our_dir, f)) for f in os.listdir(our_dir))
        os.remove(raw_path)
        shutil.rmtree(our_dir)
    payload_bytes = sum(len(payloads[k % len(payloads)]) for k in range(count))
    return {'label': label, 'count': count, 'raw': min(raw_times), 'ours': min(our_times),
            'raw_size': raw_size, 'our_size': our_size, 'bytes': payload_bytes}


# ---------------------------------------------------------------------------------------------
# Recorder end to end
# ---------------------------------------------------------------------------------------------

def _publisher_child(env, topic, type_name, payloads, count, window, rate, recorded, commands,
                     results):
    """Publish count payloads: paced at ``rate`` /s, or at most ``window`` ahead of recorded."""
    _child_signals()
    os.environ.update(env)
    from microball_ros.io.conversions import message_class

    context = rclpy.Context()
    _init(context)
    node = rclpy.create_node('bench_bags_publisher', context=context)
    try:
        publisher = node.create_publisher(message_class(type_name), topic, DATA_QOS)
        results.put(('ready',))
        commands.get(timeout=60)  # the recorder has subscribed
        deadline = time.monotonic() + 30
        while publisher.get_subscription_count() < 1 and time.monotonic() < deadline:
            time.sleep(0.01)
        m = len(payloads)
        start = time.monotonic()
        for k in range(count):
            if rate:
                due = start + k / rate
                while time.monotonic() < due:
                    time.sleep(min(0.005, max(0.0, due - time.monotonic())))
            else:
                while k - recorded.value >= window:
                    time.sleep(0.0001)
            publisher.publish(payloads[k % m])
        results.put(('done', count, start, time.monotonic()))
        commands.get(timeout=120)  # keep the writer until everything is acknowledged
    finally:
        node.destroy_node()
        if context.ok():
            rclpy.shutdown(context=context)


def _start_child(child):
    """Start a child process with SIGINT blocked, so Ctrl-C reaches only this process.

    The child inherits the blocked signal (and ignores it once running); this process gets a
    Ctrl-C that arrived meanwhile as soon as the child has started, and then stops the child.
    """
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        child.start()
    finally:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def _stop_child(child, commands=None):
    if child is None or child.pid is None:  # never started
        return
    if commands is not None and child.is_alive():
        with contextlib.suppress(Exception):
            commands.put('stop')
    child.join(timeout=5)
    if child.is_alive():
        child.terminate()
        child.join(timeout=5)
    if child.is_alive():
        child.kill()
        child.join()


def _wait_message(results, executor, kind, timeout=60.0):
    """Spin the executor until the child posts a message of ``kind``; return it."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            message = results.get_nowait()
        except queue.Empty:
            executor.spin_once(timeout_sec=0.02)
            continue
        if message[0] == kind:
            return message
    raise TimeoutError(f'no {kind!r} from the child process in {timeout:g} s')


class _BareSink:
    """Reference for the recorder: a raw subscription that only counts (no bag)."""

    def __init__(self, context, topic, type_name):
        from microball_ros.io.conversions import message_class

        self.node = rclpy.create_node('bench_bags_bare', context=context)
        self._topic = topic
        self._count = 0
        self.lost = {}
        self._subscription = self.node.create_subscription(
            message_class(type_name), topic, self._on_message, DATA_QOS, raw=True)

    def _on_message(self, data):
        self._count += 1

    @property
    def counts(self):
        return {self._topic: self._count}

    @property
    def matched(self):
        return {self._topic: self._subscription.get_publisher_count()}

    def close(self):
        return self.counts


def record_run(run, workdir, label, topic, type_name, payloads, count, window=0, rate=0.0,
               bare=False):
    """Record count messages published by a child process; return what was measured.

    ``bare``: a counting raw subscription instead of the Recorder (the rclpy floor).
    """
    from microball_ros.nodes.recorder import Recorder

    env = _dds_env(run)
    mp = multiprocessing.get_context('spawn')
    recorded = mp.RawValue('q', 0)
    commands, results = mp.Queue(), mp.Queue()
    child = mp.Process(target=_publisher_child, daemon=True, args=(
        env, topic, type_name, payloads, count, window, rate, recorded, commands, results))
    bag_dir = os.path.join(workdir, f'recorded_{run}')
    context = rclpy.Context()
    _init(context)
    recorder = node = executor = None
    result = {'label': label, 'count': count, 'size': len(payloads[0]), 'error': None,
              'sink': 'raw subscription, counting only' if bare else 'Recorder -> bag'}
    try:
        if bare:
            recorder = _BareSink(context, topic, type_name)
            node = recorder.node
        else:
            recorder = node = Recorder(context=context, parameter_overrides=[
                Parameter('output', value=bag_dir), Parameter('topics', value=[topic])])
            # Tell the publisher of each written message at once: the recorder writes a
            # backlog in one callback, and a count updated only between executor rounds
            # would stall the publisher's window meanwhile.
            write = recorder._writer.write

            def counted_write(*args):
                write(*args)
                recorded.value += 1
            recorder._writer.write = counted_write
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        _start_child(child)
        _wait_message(results, executor, 'ready')
        deadline = time.monotonic() + 30
        while recorder.matched.get(topic, 0) < 1:
            executor.spin_once(timeout_sec=0.02)
            if time.monotonic() > deadline or not child.is_alive():
                raise TimeoutError('the recorder did not subscribe')
        commands.put('go')
        cpu_start = time.process_time()
        first = last = done = None
        seen = 0
        limit = time.monotonic() + 60 + (count / rate if rate else 0)
        next_check = 0.0
        while True:
            executor.spin_once(timeout_sec=0.01)
            n = recorder.counts.get(topic, 0)
            now = time.monotonic()
            if n != seen:
                recorded.value = seen = n
                last = now
                if first is None:
                    first = now
            if done is not None and n >= done[1]:
                break
            if now < next_check:
                continue  # polling the queue costs tens of us: not after every message
            next_check = now + 0.02
            if done is None:
                with contextlib.suppress(queue.Empty):
                    done = results.get_nowait()
            if done is not None and now - max(last or 0.0, done[3]) > QUIET:
                break
            if now > limit or not child.is_alive() and done is None:
                result['error'] = 'timed out' if now > limit else 'publisher died'
                break
        cpu = time.process_time() - cpu_start
        recorder.close()
        recorded_count = recorder.counts.get(topic, 0)
        result.update(recorded=recorded_count, lost=recorder.lost.get(topic, 0),
                      sent=done[1] if done else math.nan, cpu=cpu)
        if done and recorded_count >= 1:
            result['wall'] = last - done[2]  # first publish -> last message written
            result['publisher_wall'] = done[3] - done[2]
            result['recorder_span'] = last - first
    finally:
        _stop_child(child, commands)
        if executor is not None:
            executor.shutdown()
        if node is not None:
            with contextlib.redirect_stdout(io.StringIO()):  # the recorder prints its counts
                node.destroy_node()
        if context.ok():
            rclpy.shutdown(context=context)
        shutil.rmtree(bag_dir, ignore_errors=True)
    return result


# ---------------------------------------------------------------------------------------------
# Player
# ---------------------------------------------------------------------------------------------

def _player_child(env, plays, commands, results):
    """Play each (mode, bag) of plays when told to; post ready and done messages."""
    _child_signals()
    os.environ.update(env)
    from microball_ros.app.play import Player, use_lockstep_profile
    from microball_ros.io.bags.reader import open_bag

    use_lockstep_profile()  # before rclpy.init, as microball play --lockstep does
    context = rclpy.Context()
    _init(context)
    executor = SingleThreadedExecutor(context=context)
    try:
        for mode, path in plays:
            player = Player(open_bag(path), context=context)
            executor.add_node(player)
            player.wait_for_subscribers(executor, [POSITIONS])
            results.put(('ready', mode))
            commands.get(timeout=60)
            start = time.monotonic()
            count = player.play(executor, rate=0.0, lockstep=mode == 'lock-step')
            results.put(('done', count, start, time.monotonic()))
            commands.get(timeout=120)  # the subscriber has all it will get
            executor.remove_node(player)
            player.destroy_node()
    finally:
        executor.shutdown()
        if context.ok():
            rclpy.shutdown(context=context)


def _profiled_player_child(run, workdir, plays, results):
    from microball_ros.app.play import use_lockstep_profile

    use_lockstep_profile()  # this process's subscriber answers heartbeats after 0.1 ms
    results.put(player_runs(run, workdir, plays))


def profiled_player_runs(run, workdir, plays):
    """player_runs from a process whose subscriber loads the lock-step profile too.

    As in ``microball reprocess``, where every node process loads it. The Fast DDS profile is
    read once per process, so this needs a process that has not started DDS yet.
    """
    mp = multiprocessing.get_context('spawn')
    results = mp.Queue()
    child = mp.Process(target=_profiled_player_child, args=(run, workdir, plays, results))
    child.start()
    try:
        return results.get(timeout=600)
    finally:
        child.join(timeout=30)
        if child.is_alive():
            child.terminate()


def write_positions_bag(directory, payloads, count):
    """Write count TrackedPositions at 30 Hz into a bag; return its path."""
    with BagWriter(directory) as bag:
        bag.add_topic(POSITIONS, POSITIONS_TYPE, qos_profiles_yaml([DATA_QOS]))
        period = int(1e9 / FPS)
        for k in range(count):
            bag.write(POSITIONS, payloads[k % len(payloads)], k * period, k * period)
    return directory


def player_runs(run, workdir, plays):
    """Play the bags from a child process to a subscriber here; return one dict per play."""
    from microball_msgs.msg import TrackedPositions

    env = _dds_env(run)
    mp = multiprocessing.get_context('spawn')
    commands, results = mp.Queue(), mp.Queue()
    child = mp.Process(target=_player_child, args=(env, plays, commands, results), daemon=True)
    context = rclpy.Context()
    _init(context)
    node = rclpy.create_node('bench_bags_subscriber', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    state = {'received': 0, 'last': None}

    def on_message(msg):
        state['received'] += 1
        state['last'] = time.monotonic()

    subscription = node.create_subscription(TrackedPositions, POSITIONS, on_message, DATA_QOS)
    measured = []
    try:
        _start_child(child)
        for mode, _ in plays:
            _wait_message(results, executor, 'ready')
            deadline = time.monotonic() + 30
            while subscription.get_publisher_count() < 1 and time.monotonic() < deadline:
                executor.spin_once(timeout_sec=0.02)
            state['received'], state['last'] = 0, None
            commands.put('go')
            done = _wait_message(results, executor, 'done', timeout=300)
            _, count, start, end = done
            while state['received'] < count:
                executor.spin_once(timeout_sec=0.02)
                if time.monotonic() - max(state['last'] or 0.0, end) > QUIET:
                    break
            measured.append({'mode': mode, 'published': count, 'received': state['received'],
                             'player_wall': end - start,
                             'wall': (state['last'] or math.nan) - start})
            commands.put('next')
    finally:
        _stop_child(child, commands)
        executor.shutdown()
        node.destroy_node()
        if context.ok():
            rclpy.shutdown(context=context)
    return measured


# ---------------------------------------------------------------------------------------------
# Analysis
# ---------------------------------------------------------------------------------------------

def tiled_record(duration, clean=None):
    """Return (time, stator, slider) of bench.simulate('paper', duration), built by tiling.

    The noise-free motion of a TILE-second stretch repeats (the slider creeping by a constant
    per tile); the noise and drift are drawn for the whole duration as bench.simulate draws
    them. Also return the worst periodicity error of the noise-free motion, m.
    """
    scenario = bench.get_scenario(SCENARIO)
    if clean is None:
        clean = bench.simulate(replace(scenario, noise_std=0.0, drift_velocity=0.0), 2 * TILE)
    fr = scenario.frame_rate
    n_tile = round(TILE * fr)
    stator_tile = clean.stator_position[:n_tile]
    slider_tile = clean.slider_position[:n_tile]
    creep = float(np.mean(clean.slider_position[n_tile:2 * n_tile] - slider_tile))
    error = max(np.abs(clean.stator_position[n_tile:2 * n_tile] - stator_tile).max(),
                np.abs(clean.slider_position[n_tile:2 * n_tile] - slider_tile - creep).max())
    n = math.floor(duration * fr + 1e-9)
    k = np.arange(n)
    rng = np.random.default_rng(scenario.seed)
    stator_noise = rng.standard_normal(n) * scenario.noise_std
    slider_noise = rng.standard_normal(n) * scenario.noise_std
    drift = bench.slider_drift(rng, n, 1.0 / fr, scenario.drift_velocity, scenario.drift_time)
    stator = stator_tile[k % n_tile] + stator_noise
    slider = slider_tile[k % n_tile] + (k // n_tile) * creep + drift + slider_noise
    return k / fr, stator, slider, clean, float(error)


class _StageClock:
    """Time analyze_record's stages by wrapping the core functions it calls (outermost only)."""

    STAGES = {(estimation, 'relative_memory_test'): 'estimate',
              (estimation, 'estimate_relative'): 'estimate',
              (friction, 'fit_least_squares'): 'fit', (friction, 'compare_laws'): 'fit',
              (friction, 'validate'): 'validation'}

    def __init__(self):
        self.spent = {}
        self._depth = 0
        self._saved = {}

    def _wrap(self, function, stage):
        def timed(*args, **kwargs):
            if self._depth:
                return function(*args, **kwargs)
            self._depth += 1
            start = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                self.spent[stage] = self.spent.get(stage, 0.0) + time.perf_counter() - start
                self._depth -= 1
        return timed

    def __enter__(self):
        for (module, name), stage in self.STAGES.items():
            self._saved[module, name] = getattr(module, name)
            setattr(module, name, self._wrap(self._saved[module, name], stage))
        return self

    def __exit__(self, *exc_info):
        for (module, name), function in self._saved.items():
            setattr(module, name, function)
        return False


def timed_analysis(record, exposure, repeats=3):
    """Run analyze_record repeats times; return (result, total s, {stage: s}) of the fastest."""
    best = None
    for _ in range(repeats):
        with _StageClock() as clock:
            start = time.perf_counter()
            result = analysis.analyze_record(record, exposure=exposure)
            total = time.perf_counter() - start
        stages = dict(clock.spent)
        stages['other'] = total - sum(stages.values())
        if best is None or total < best[1]:
            best = result, total, stages
    return best


def write_record_bag(directory, time_s, stator, slider):
    """Write the positions as TrackedPositions into a bag with BagWriter; return wall s."""
    start = time.perf_counter()
    with BagWriter(directory) as bag:
        bag.add_topic(POSITIONS, POSITIONS_TYPE, qos_profiles_yaml([DATA_QOS]))
        for k in range(len(time_s)):
            stamp = int(round(time_s[k] * 1e9))
            data = serialize_message(conversions.tracked_positions(
                time_s[k], k, slider[k], stator[k], 1.0, 1.0))
            bag.write(POSITIONS, data, stamp, stamp)
    return time.perf_counter() - start


# ---------------------------------------------------------------------------------------------
# Tables
# ---------------------------------------------------------------------------------------------

def _f(value, digits=1):
    return 'n/a' if not math.isfinite(value) else f'{value:,.{digits}f}'


def recorder_table(runs, costs):
    """Return the Markdown lines of the end-to-end recorder table."""
    lines = ['| payload | receiver | bytes/msg | sent | received | lost (events) | msgs/s '
             '| MB/s | receiver CPU (1 core) | receiver CPU us/msg | raw mcap Writer msgs/s '
             '| ratio ours/raw (time/msg) | within 1.5x |',
             '|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|']
    for run in runs:
        cost = costs[run['label']]
        raw_rate = cost['count'] / cost['raw']
        wall = run.get('wall', math.nan)
        rate = run['recorded'] / wall if wall > 0 else math.nan
        ratio = raw_rate / rate
        verdict = 'yes' if ratio <= RATIO_GOAL else 'no'
        if run['sink'] != 'Recorder -> bag':
            verdict = '(reference)'
        lines.append(
            f"| {run['label']} | {run['sink']} | {run['size']:,} | {run['sent']:,} "
            f"| {run['recorded']:,} "
            f"| {run['lost']} | {_f(rate)} | {_f(rate * run['size'] / MB)} "
            f"| {_f(100 * run['cpu'] / wall, 0)} % | {_f(1e6 * run['cpu'] / run['recorded'])} "
            f"| {_f(raw_rate)} | {_f(ratio, 2)} "
            f"| {verdict} |")
    return lines


def write_table(costs):
    """Return the Markdown lines of the pure write cost table."""
    lines = ['| payload | messages | BagWriter us/msg | BagWriter msgs/s | BagWriter MB/s '
             '| raw Writer us/msg | raw msgs/s | raw MB/s | ratio ours/raw | within 1.5x '
             '| file MB ours / raw |',
             '|---|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|']
    for cost in costs.values():
        n, ours, raw = cost['count'], cost['ours'], cost['raw']
        lines.append(
            f"| {cost['label']} | {n:,} | {_f(1e6 * ours / n, 2)} | {_f(n / ours)} "
            f"| {_f(cost['bytes'] / ours / MB)} | {_f(1e6 * raw / n, 2)} | {_f(n / raw)} "
            f"| {_f(cost['bytes'] / raw / MB)} | {ours / raw:.2f} "
            f"| {'yes' if ours / raw <= RATIO_GOAL else 'no'} "
            f"| {cost['our_size'] / MB:.2f} / {cost['raw_size'] / MB:.2f} |")
    return lines


def paced_table(run):
    """Return the Markdown lines of the 30 fps frames table."""
    span = run.get('recorder_span', math.nan)
    achieved = (run['recorded'] - 1) / span if span > 0 else math.nan
    published = (run['sent'] - 1) / run['publisher_wall'] if run.get('publisher_wall') \
        else math.nan
    sustained = run['recorded'] == run['sent'] and run['lost'] == 0 and achieved >= 0.99 * FPS
    return ['| frames sent | recorded | lost (events) | publisher fps | recorder fps (first to '
            'last written) | achieved / 30 | recorder CPU (1 core) | sustained |',
            '|---:|---:|---:|---:|---:|---:|---:|---|',
            f"| {run['sent']} | {run['recorded']} | {run['lost']} | {_f(published, 2)} "
            f"| {_f(achieved, 2)} | {_f(achieved / FPS, 3)} "
            f"| {_f(100 * run['cpu'] / run['wall'], 0)} % | {'yes' if sustained else 'NO'} |"]


def player_table(plays):
    """Return the Markdown lines of the player table."""
    lines = ['| mode | published | received | player msgs/s (publish loop) '
             '| end-to-end msgs/s (to last received) | x real time (30 msgs/s) |',
             '|---|---:|---:|---:|---:|---:|']
    for play in plays:
        player_rate = play['published'] / play['player_wall']
        rate = play['received'] / play['wall'] if play['wall'] > 0 else math.nan
        lines.append(f"| {play['mode']} | {play['published']:,} | {play['received']:,} "
                     f"| {_f(player_rate)} | {_f(rate)} | {_f(rate / FPS, 1)} |")
    return lines


def analysis_table(rows):
    """Return the Markdown lines of the analysis table."""
    lines = ['| source | samples | read s | estimate + memory test s | fit s | validation s '
             '| other s | total s | total / 2 s goal | A (m/s^2), alpha (s/m) |',
             '|---|---:|---:|---:|---:|---:|---:|---:|---:|---|']
    for row in rows:
        stages, read = row['stages'], row['read']
        total = row['total'] + (read if math.isfinite(read) else 0.0)
        params = row['result'].fit.params
        lines.append(
            f"| {row['source']} | {row['samples']:,} | {_f(read, 2)} "
            f"| {stages.get('estimate', 0.0):.2f} | {stages.get('fit', 0.0):.2f} "
            f"| {stages.get('validation', 0.0):.2f} | {stages['other']:.2f} | {total:.2f} "
            f"| {total / ANALYSIS_GOAL:.1f} | {params['A']:.4g}, {params['alpha']:.4g} |")
    return lines


# ---------------------------------------------------------------------------------------------

def run_all(args, workdir, out):
    """Run every measurement; append report lines to out."""
    positions = position_payloads()
    frames = frame_payloads()
    _log(f'payloads: TrackedPositions {len(positions[0])} B, Image {len(frames[0]):,} B')

    _log('pure write cost: BagWriter vs raw mcap Writer')
    costs = {'TrackedPositions': write_cost(workdir, 'TrackedPositions', POSITIONS,
                                            POSITIONS_TYPE, positions, args.small_count),
             '720x480 mono8 Image': write_cost(workdir, '720x480 mono8 Image', IMAGES,
                                               IMAGE_TYPE, frames, args.frame_count)}

    _log('recorder end to end: small messages at the highest rate')
    runs = [record_run(0, workdir, 'TrackedPositions', POSITIONS, POSITIONS_TYPE, positions,
                       args.small_count // 2, window=200)]
    _log('recorder end to end: frames at the highest rate')
    runs.append(record_run(1, workdir, '720x480 mono8 Image', IMAGES, IMAGE_TYPE, frames,
                           args.frame_count, window=10))
    _log('reference: a bare raw subscription (counting only) at the highest rate')
    runs.append(record_run(4, workdir, 'TrackedPositions', POSITIONS, POSITIONS_TYPE,
                           positions, args.small_count // 2, window=200, bare=True))
    runs.append(record_run(5, workdir, '720x480 mono8 Image', IMAGES, IMAGE_TYPE, frames,
                           args.frame_count, window=10, bare=True))
    _log('recorder end to end: frames paced at 30 fps')
    paced = record_run(2, workdir, 'Image 30 fps', IMAGES, IMAGE_TYPE, frames,
                       round(args.paced_seconds * FPS), rate=FPS)

    _log('player: lock-step, then the highest rate')
    lock_bag = write_positions_bag(os.path.join(workdir, 'lockstep'), positions,
                                   args.lockstep_count)
    fast_bag = write_positions_bag(os.path.join(workdir, 'maxrate'), positions,
                                   args.maxrate_count)
    plays = player_runs(3, workdir, [('lock-step, subscriber without the profile', lock_bag),
                                     ('not lock-step, rate 0 (no pacing)', fast_bag)])
    _log('player: lock-step to a subscriber with the lock-step profile (as in reprocess)')
    plays[1:1] = profiled_player_runs(6, workdir, [
        ('lock-step, subscriber with the profile (as in reprocess)', lock_bag)])

    _log(f'analysis: building {args.analysis_duration:g} s of positions')
    exposure = bench.get_scenario(SCENARIO).exposure
    start = time.perf_counter()
    time_s, stator, slider, clean, periodic_error = tiled_record(args.analysis_duration)
    build = time.perf_counter() - start
    check_start = time.perf_counter()
    genuine = bench.simulate(bench.get_scenario(SCENARIO), args.check_duration)
    check_time = time.perf_counter() - check_start
    _, check_stator, check_slider, _, _ = tiled_record(args.check_duration, clean)
    check_error = max(np.abs(check_stator - genuine.stator_position).max(),
                      np.abs(check_slider - genuine.slider_position).max())
    record = PositionRecord(time=time_s, stator_position=stator,
                                     slider_position=slider)
    _log('analysis: in memory')
    result, total, stages = timed_analysis(record, exposure)
    rows = [{'source': 'in memory', 'samples': len(time_s), 'read': math.nan, 'total': total,
             'stages': stages, 'result': result}]
    bag_dir = os.path.join(workdir, 'hour')
    _log('analysis: writing the bag')
    bag_write = write_record_bag(bag_dir, time_s, stator, slider)
    bag_size = sum(os.path.getsize(os.path.join(bag_dir, f)) for f in os.listdir(bag_dir))
    reads = []
    for _ in range(3):
        start = time.perf_counter()
        loaded = analysis.load_positions(bag_dir)
        reads.append(time.perf_counter() - start)
    read = min(reads)
    same = (np.array_equal(loaded.stator_position, stator)
            and np.array_equal(loaded.slider_position, slider))
    time_error = float(np.abs(loaded.time - time_s).max())
    if not args.skip_bag_analysis:
        _log('analysis: from the bag')
        result, total, stages = timed_analysis(loaded, exposure)
        rows.append({'source': 'from a bag (load_positions)', 'samples': len(loaded.time),
                     'read': read, 'total': total, 'stages': stages, 'result': result})


    out += ['## Recorder end to end (publisher process -> Recorder node -> bag, zero loss)\n',
            f'A publisher process keeps at most 200 small messages (10 frames) in flight beyond '
            f'what the recorder has written; {runs[0]["count"]:,} TrackedPositions and '
            f'{runs[1]["count"]} frames. msgs/s = recorded / (first publish -> last written); '
            f'CPU = this process (recorder node, executor and DDS threads) over that time. '
            f'The reference rows replace the Recorder by a raw subscription that only counts '
            f'(same QoS, executor and loop): what rclpy delivers to one callback per message. '
            f'The Recorder takes the backlog of its topic itself in one callback (up to '
            f'DRAIN_LIMIT messages), which avoids most of that executor cost. '
            f'The raw column is the raw mcap Writer on the same payloads in this process '
            f'(table below), so the ratio is the whole cost of receiving through DDS and '
            f'rclpy plus writing, against writing alone.\n', *recorder_table(runs, costs),
            f'\nFrames at the highest rate: '
            f'{_f(runs[1]["recorded"] / runs[1].get("wall", math.nan), 1)} frames/s = '
            f'{_f(runs[1]["recorded"] / runs[1].get("wall", math.nan) / FPS, 2)} x 30 fps.\n',
            '## Pure write cost (no DDS): BagWriter vs raw mcap Writer, identical payloads\n',
            f'zstd, {CHUNK_SIZE // 1024} KiB chunks, open to close (fsync) included; best of 3 '
            f'alternating repetitions; {len(positions)} distinct TrackedPositions and '
            f'{len(frames)} distinct rendered frames cycled.\n', *write_table(costs), '',
            f'## 720 x 480 mono8 frames paced at 30 fps ({args.paced_seconds:g} s)\n',
            *paced_table(paced), '',
            '## Player: Player.play from a child process to one subscriber\n',
            f'Lock-step: {args.lockstep_count} TrackedPositions, each published after the '
            f'previous one is acknowledged (the player loads config/fastdds_lockstep.xml: '
            f'1 ms writer heartbeats). A subscriber without the profile acknowledges a '
            f"heartbeat after Fast DDS's default 5 ms; with it (as every node process of "
            f'microball reprocess), after 0.1 ms. Highest rate: {args.maxrate_count:,} '
            f'messages, no pacing, subscriber KEEP_LAST 2000 (DATA_QOS).\n',
            *player_table(plays), '',
            f"## Analysis of {args.analysis_duration / 3600:g} h of 30 fps positions "
            f"('{SCENARIO}', {len(time_s):,} samples)\n",
            f'Record built in {build:.1f} s by tiling a {TILE:g} s noise-free stretch '
            f'(periodicity error {periodic_error:.1e} m) and drawing the noise and drift for the '
            f'whole record as bench.simulate does; checked against bench.simulate on '
            f'{args.check_duration:g} s: max difference {check_error:.1e} m (bench.simulate '
            f'itself took {check_time:.1f} s for those {args.check_duration:g} s, i.e. about '
            f'{check_time * 3600 / args.check_duration:.0f} s for an hour). Bag: written by '
            f'BagWriter in {bag_write:.1f} s ({bag_size / MB:.1f} MB, zstd); load_positions '
            f'gives {"identical" if same else "DIFFERENT"} positions, stamps within '
            f'{time_error:.1e} s. Each figure is the best of 3 runs (read and analysis '
            f'separately). Stages: estimate + memory test = relative_memory_test and '
            f'the re-estimate at fit_epsilon; fit = fit_least_squares + compare_laws; '
            f'validation = friction.validate; other = the valid window, fundamental frequency '
            f'and oscillation check.\n', *analysis_table(rows)]
    if args.skip_bag_analysis:
        out.append(f'\n(--skip-bag-analysis: the bag was read in {read:.2f} s but not '
                   f'analysed again.)')
    for run in [*runs, paced]:
        if run['error']:
            out.append(f"\n{run['label']}: {run['error']}")



def main():
    """Run the benchmark and print its tables."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--analysis-duration', type=float, default=3600.0,
                        help='seconds of 30 fps positions to analyse (default 3600)')
    parser.add_argument('--check-duration', type=float, default=60.0,
                        help='seconds of bench.simulate to check the tiling against (default 60)')
    parser.add_argument('--skip-bag-analysis', action='store_true',
                        help='read the bag but do not analyse it a second time')
    parser.add_argument('--small-count', type=int, default=60000,
                        help='TrackedPositions per write-cost run (the recorder gets half)')
    parser.add_argument('--frame-count', type=int, default=300,
                        help='frames per write-cost run and per highest-rate recorder run')
    parser.add_argument('--paced-seconds', type=float, default=5.0,
                        help='seconds of frames paced at 30 fps (default 5)')
    parser.add_argument('--lockstep-count', type=int, default=600,
                        help='messages played lock-step (default 600)')
    parser.add_argument('--maxrate-count', type=int, default=10000,
                        help='messages played at the highest rate (default 10000)')
    args = parser.parse_args()
    signal.signal(signal.SIGTERM, _interrupt)
    started = time.monotonic()
    load_start = _loadavg()
    workdir = tempfile.mkdtemp(prefix='microball-bench-bags-')
    out = []
    try:
        run_all(args, workdir, out)
    except KeyboardInterrupt:
        _log('interrupted; child processes stopped, temporary bags removed')
        return 130
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    runtime = time.monotonic() - started
    print('# microball_ros bag benchmark\n')
    print(f'{os.cpu_count()} CPUs; load average (1, 5, 15 min) at start: {load_start}; '
          f"RMW: {os.environ.get('RMW_IMPLEMENTATION', 'default (rmw_fastrtps_cpp)')}; "
          f'ratio ours/raw = time per message ours / raw (goal <= {RATIO_GOAL}).\n')
    print('\n'.join(out))
    print(f'\nLoad average at end: {_loadavg()}; benchmark runtime {runtime:.0f} s. The '
          '2-core machine is shared and noisy: other jobs inflate wall times and CPU shares, '
          'so treat the figures as +-10-20 % and compare runs made under similar load.')
    return 0


if __name__ == '__main__':
    sys.exit(main())
