"""``microball experiment``: run every node of the rig as its own process over DDS.

Starts servo_commander, bench_simulator, camera_tracker, three_stage_estimator and
friction_identifier as separate processes (``python -m microball_ros.nodes.<name>``), watches
their topics from a monitor node in this process, shows progress, and stops them all at the
end, on Ctrl-C, or when one of them dies (saying which and why). Children also get SIGTERM if
this process is killed outright (Linux parent-death signal), so no node is left orphaned.

Never mixed with another rig: the run claims a ROS domain of its own (app/isolation.py), and
the monitor watches every topic of the run for a publisher it did not start or a sequence
going backwards; either stops the run with an IsolationError (exit 2, one line).
"""

import ctypes
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time

from diagnostic_msgs.msg import DiagnosticArray
from microball_msgs.msg import BenchState, DerivativeEstimate, FrictionModel, TrackedPositions
import numpy as np
import rclpy
from rclpy.executors import SingleThreadedExecutor
import yaml

from microball_ros.app.isolation import ForeignPublisherCheck, IsolationError, claim_domain
from microball_ros.core import bench, rig
from microball_ros.nodes.camera_tracker import reliable_images
from microball_ros.nodes.common import DATA_QOS, diagnostic_values, subscribers_key

NODES = ('servo_commander', 'bench_simulator', 'camera_tracker', 'three_stage_estimator',
         'friction_identifier')
_PR_SET_PDEATHSIG = 1


class NodeCrashed(RuntimeError):
    """A node process exited while the experiment was running."""


def _die_with_parent():
    """Ask the kernel to SIGTERM this child when its parent dies (runs in the child)."""
    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)


def node_parameters(scenario_name, duration, speed, output=None, params_file=None):
    """Return node name -> parameter dict for an experiment on the named scenario.

    With ``output`` a recorder joins, recording every topic, and the bag's metadata keeps the
    tracker's, estimator's and identifier's parameters (for ``microball reprocess``, and to
    track the frames of a bag cut down to them). ``params_file`` is a ROS 2 parameters file
    (config/microball.yaml's form: node name -> ros__parameters); its values override the
    scenario's per node, except the run control the experiment's own options set (RUN_CONTROL).
    A file that is missing, not such YAML, or names an unknown node or parameter raises
    InputError.
    """
    import importlib

    from microball_ros.core.errors import InputError

    overrides = {}
    if params_file:
        try:
            with open(params_file) as handle:
                loaded = yaml.safe_load(handle)
        except OSError as error:
            raise InputError(f'{params_file}: {error.strerror}') from None
        except yaml.YAMLError:
            raise InputError(f'{params_file}: not YAML') from None
        if not isinstance(loaded, dict) or not all(
                isinstance(v, dict) and isinstance(v.get('ros__parameters'), dict)
                for v in loaded.values()):
            raise InputError(f'{params_file}: not a ROS 2 parameters file (node name -> '
                             'ros__parameters)')
        for key, section in loaded.items():
            name = str(key).lstrip('/')
            known = NODES + ('recorder', 'camera_source')
            if name not in known:
                raise InputError(f'{params_file}: unknown node {key!r}; known: '
                                 f'{", ".join(known)}')
            declared = importlib.import_module(f'microball_ros.nodes.{name}').PARAMS
            flat = flatten_parameters(section['ros__parameters'])
            unknown = [p for p in flat if p not in declared and p != 'use_sim_time'
                       and not p.startswith('qos_overrides.')]
            if unknown:
                raise InputError(f'{params_file}: {name} has no parameter '
                                 f'{", ".join(sorted(unknown))}')
            overrides[name] = {k: v for k, v in flat.items()
                               if k not in RUN_CONTROL.get(name, ())}
    scenario = bench.get_scenario(scenario_name)
    rois = rig.suggested_rois(scenario)
    sim_time = {'use_sim_time': True} if speed != 1.0 else {}
    parameters = {
        'servo_commander': {'frequency': scenario.frequency,
                            'amplitude': scenario.stator_amplitude, 'ramp_time': 1.0,
                            **sim_time},
        'bench_simulator': {'scenario': scenario_name, 'speed': float(speed),
                            'publish_clock': speed != 1.0, 'duration': float(duration),
                            'wait_for_subscribers': 2 if output else 1},
        'camera_tracker': {'slider_roi': list(rois['slider']),
                           'stator_roi': list(rois['stator']),
                           'meters_per_pixel': rig.camera_for(scenario).meters_per_pixel,
                           **sim_time},
        'three_stage_estimator': {'exposure': rig.camera_for(scenario).exposure, **sim_time},
        'friction_identifier': {'exposure': rig.camera_for(scenario).exposure, **sim_time},
    }
    # Inside a run every frame must reach the tracker even when it falls seconds behind.
    for name, role in (('bench_simulator', 'publisher'), ('camera_tracker', 'subscription')):
        parameters[name].update(flatten_parameters({'qos_overrides': reliable_images(role)}))
    for name in parameters:
        parameters[name].update(overrides.get(name, {}))
    if output:
        kept = {f'microball.{name}': yaml.safe_dump(
            {k: v for k, v in parameters[name].items() if k != 'use_sim_time'})
            for name in ('camera_tracker', 'three_stage_estimator', 'friction_identifier')}
        parameters['recorder'] = {**overrides.get('recorder', {}), 'output': output,
                                  'custom_data': yaml.safe_dump(kept)}
    return parameters


# Parameters the experiment's own options set (a --params file cannot change them).
RUN_CONTROL = {'bench_simulator': ('scenario', 'speed', 'publish_clock', 'duration',
                                   'wait_for_subscribers'),
               'recorder': ('output', 'custom_data'),
               'camera_tracker': ('video_path', 'wait_for_subscribers')}


def flatten_parameters(mapping, prefix=''):
    """Return nested ros__parameters as dotted name -> value (as ROS 2 reads them)."""
    flat = {}
    for key, value in mapping.items():
        if isinstance(value, dict):
            flat.update(flatten_parameters(value, f'{prefix}{key}.'))
        else:
            flat[f'{prefix}{key}'] = value
    return flat


# Every subscription the pipeline needs before the bench's first frame: topic -> count
# (the monitor of this process counts as one).
_READY = {'camera/image_raw': 1, 'tracking/positions': 2, 'estimation/derivatives': 2}
# ... and with a recorder, one more on each topic that has its publisher already; the bench
# waits for the recorder on its own topics (wait_for_subscribers = 2).
_READY_RECORDING = {'camera/image_raw': 1, 'tracking/positions': 3,
                    'estimation/derivatives': 3, 'friction/model': 2, 'servo/command': 1}
# The node that writes each topic and reports, on /diagnostics, how many subscriptions its
# writer has matched: the graph shows a subscription before the writer has matched it, and
# what the writer publishes before that is lost (volatile QoS).
WRITERS = {'tracking/positions': 'camera_tracker',
            'estimation/derivatives': 'three_stage_estimator',
            'friction/model': 'friction_identifier'}


class NodeProcesses:
    """The node processes, their logs, and their orderly (or forced) end."""

    def __init__(self, parameters, log_dir, env=None):
        self.log_dir = log_dir
        self.parameters = parameters
        self.env = env
        self.procs = {}

    def start(self, name):
        """Start one node process with its parameters file; its output goes to its log."""
        params = os.path.join(self.log_dir, f'{name}.params.yaml')
        with open(params, 'w') as handle:
            yaml.safe_dump({'/**': {'ros__parameters': self.parameters[name]}}, handle)
        args = [sys.executable, '-m', f'microball_ros.nodes.{name}', '--ros-args',
                '--params-file', params]
        log = open(os.path.join(self.log_dir, f'{name}.log'), 'w')
        self.procs[name] = (subprocess.Popen(args, stdout=log, stderr=subprocess.STDOUT,
                                             stdin=subprocess.DEVNULL, env=self.env,
                                             preexec_fn=_die_with_parent), log)

    def check(self):
        """Raise NodeCrashed naming the first node that has exited."""
        for name, (proc, _) in self.procs.items():
            code = proc.poll()
            if code is not None and code < 0:  # killed from outside: its log is not the cause
                raise NodeCrashed(f'node {name} exited with code {code} (killed by '
                                  f'{signal.Signals(-code).name}); its log: '
                                  f'{os.path.join(self.log_dir, name + ".log")}')
            if code is not None:
                raise NodeCrashed(f'node {name} exited with code {code}: {self.last_line(name)}')

    def last_line(self, name):
        """Return the last non-empty line of a node's log."""
        with open(os.path.join(self.log_dir, f'{name}.log')) as handle:
            lines = [line.strip() for line in handle if line.strip()]
        return lines[-1] if lines else '(no output)'

    def stop(self, grace=5.0):
        """SIGINT every node, then SIGKILL whatever is still running after grace seconds."""
        for proc, _ in self.procs.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        deadline = time.monotonic() + grace
        for proc, log in self.procs.values():
            try:
                proc.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            log.close()


# Publishers this run starts on each topic; one more is another rig on the same domain.
RUN_PUBLISHERS = {'/servo/command': 1, '/camera/image_raw': 1, '/bench/ground_truth': 1,
                  '/tracking/positions': 1, '/estimation/derivatives': 1, '/friction/model': 1}


class _Monitor:
    """Counts what the nodes publish; holds the newest model and every window's verdict.

    It also watches for another rig: ``foreign`` is fed every tracked frame's index and every
    ground-truth stamp, and ``check_graph`` compares the publisher counts with the run's.
    """

    def __init__(self, context):
        self.node = rclpy.create_node('microball_experiment_monitor', context=context)
        self.frames = 0
        self.tracked = 0
        self.windows = []
        self.models = []
        self.last_change = time.monotonic()
        self.foreign = ForeignPublisherCheck(RUN_PUBLISHERS)
        self.statuses = {}  # node name -> its newest /diagnostics values
        self.node.create_subscription(DiagnosticArray, '/diagnostics',
                                      lambda msg: self.statuses.update(diagnostic_values(msg)),
                                      10)
        for message_type, topic, callback in (
                (BenchState, 'bench/ground_truth', self._on_frame),
                (TrackedPositions, 'tracking/positions', self._on_tracked),
                (DerivativeEstimate, 'estimation/derivatives', self._on_window),
                (FrictionModel, 'friction/model', self._on_model)):
            self.node.create_subscription(message_type, topic, callback, DATA_QOS)

    def _touch(self):
        self.last_change = time.monotonic()

    def writers_matched(self, ready):
        """Return True once each node's writer has matched the subscriptions ready counts."""
        return all(int(self.statuses.get(node, {}).get(subscribers_key(topic), 0))
                   >= ready.get(topic, 1) for topic, node in WRITERS.items())

    def _on_frame(self, msg):
        self.frames += 1
        self.foreign.observe('/bench/ground_truth',
                             msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
        self._touch()

    def _on_tracked(self, msg):
        self.tracked += 1
        self.foreign.observe('/tracking/positions', msg.frame_index)
        self._touch()

    def check_graph(self):
        """Return a one-line problem if a topic has a publisher this run did not start."""
        return self.foreign.check({topic: self.node.count_publishers(topic)
                                   for topic in RUN_PUBLISHERS})

    def _on_window(self, msg):
        self.windows.append((msg.phase_difference, msg.phase_uncertainty, msg.memoryless))
        self._touch()

    def _on_model(self, msg):
        self.models.append(msg)
        self._touch()

    def progress(self, fps):
        """Return a one-line progress report."""
        windows = len(self.windows)
        line = (f'simulated {self.frames / fps:5.1f} s: {self.tracked} frames tracked, '
                f'{windows} window{"" if windows == 1 else "s"}')
        if self.models:
            model = self.models[-1]
            line += f', model A = {model.a:.3g} m/s^2, alpha = {model.alpha:.3g} s/m'
        return line


def _interval(bounds):
    return '[' + ', '.join('inf' if math.isinf(b) else f'{b:.4g}' for b in bounds) + ']'


def summary_lines(monitor, scenario_name):
    """Return the final report: model with intervals, phase difference and verdict."""
    if not monitor.windows or not monitor.models:
        return ['no complete analysis window: run longer (--duration)']
    phases = np.array([w[0] for w in monitor.windows])
    memoryless = sum(1 for w in monitor.windows if w[2])
    verdict = 'memoryless' if memoryless > len(monitor.windows) / 2 else \
        'HYSTERETIC (friction has memory)'
    model = monitor.models[-1]
    truth = bench.get_scenario(scenario_name).law
    notes = [f'WARNING [{text}' .replace(':', ']:', 1) for text in model.warnings]
    return [
        f'memory test: {memoryless} of {len(monitor.windows)} windows memoryless; phase '
        f'difference median {np.median(phases):.4f} rad (range {phases.min():.4f} .. '
        f'{phases.max():.4f}; pi = 3.1416): {verdict}',
        f'Langevin model from {model.sample_count} samples in {model.window_count} windows: '
        f'A = {model.a:.4g} m/s^2 {_interval(model.a_ci95)}, alpha = {model.alpha:.4g} s/m '
        f'{_interval(model.alpha_ci95)}, rmse {model.rmse:.3g} m/s^2',
        f'validation (Fig. 9): slider amplitude {model.slider_amplitude_simulated * 1e3:.4f} mm '
        f'simulated vs {model.slider_amplitude_measured * 1e3:.4f} mm measured, phase '
        f'{model.phase_simulated:.3f} vs {model.phase_measured:.3f} rad',
        f'memory verdict of the whole record (loop test, as `microball analyze`): '
        f'{model.memory_verdict}',
        *notes,
        f'bench truth: {truth.name} {truth.params}',
    ]


def run_experiment(scenario_name, duration, speed, progress=print, quiet_period=3.0,
                   output=None, domain_id=None, params_file=None):
    """Run the experiment; return the monitor (counts, windows, models) when it is done.

    Done means: the bench has published every frame of ``duration``, each was tracked, and
    nothing new has arrived for ``quiet_period`` wall seconds (the estimator and identifier
    have drained their queues). The run claims ``domain_id`` or a free ROS domain and keeps
    discovery on this machine unless ROS_AUTOMATIC_DISCOVERY_RANGE says otherwise. Raises
    NodeCrashed if a node dies, IsolationError if the domain is taken or another rig's
    messages show up.
    """
    scenario = bench.get_scenario(scenario_name)
    fps = rig.camera_for(scenario).fps
    expected_frames = math.floor(duration * fps + 1e-9)
    parameters = node_parameters(scenario_name, duration, speed, output, params_file)
    ready = _READY_RECORDING if output else _READY
    claim = claim_domain(domain_id)
    env = claim.environment()
    progress(f'experiment: scenario {scenario_name!r}, {duration:g} s simulated at {speed:g}x '
             f'in ROS domain {claim.domain_id} (held by this run, discovery '
             f"{env['ROS_AUTOMATIC_DISCOVERY_RANGE'].lower()}); starting the nodes ...")
    log_dir = tempfile.mkdtemp(prefix='microball-experiment-')
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=claim.domain_id)
    monitor = _Monitor(context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(monitor.node)
    processes = NodeProcesses(parameters, log_dir, env=env)
    node = monitor.node
    completed = False
    try:
        wall_limit = time.monotonic() + 60.0 + 4.0 * duration / speed
        next_graph_check = 0.0

        def spin_until(condition, what):
            nonlocal next_graph_check
            while not condition():
                executor.spin_once(timeout_sec=0.1)
                processes.check()
                now = time.monotonic()
                if now >= next_graph_check:
                    monitor.check_graph()
                    next_graph_check = now + 0.5
                if monitor.foreign.problem:
                    where = f'; the bag {output} may hold its messages' if output else ''
                    raise IsolationError(f'{monitor.foreign.problem}{where}; run stopped')
                if now > wall_limit:
                    raise NodeCrashed(f'timed out waiting for {what}; node logs in {log_dir}')

        # Downstream first; the bench starts once every subscription is in place and every
        # node's writer has matched it, and holds its first frame until its own subscribers
        # are matched, so no frame is lost.
        for name in NODES + (('recorder',) if output else ()):
            if name != 'bench_simulator':
                processes.start(name)
        spin_until(lambda: all(node.count_subscribers(topic) >= count
                               for topic, count in ready.items())
                   and monitor.writers_matched(ready), 'the nodes to connect')
        processes.start('bench_simulator')
        progress('nodes connected; the bench is running')
        next_report = time.monotonic() + 2.0

        def done():
            nonlocal next_report
            now = time.monotonic()
            if now >= next_report:
                progress(monitor.progress(fps))
                next_report = now + 2.0
            finished = monitor.frames >= expected_frames and monitor.tracked >= expected_frames
            return finished and now - monitor.last_change > quiet_period

        spin_until(done, 'the analysis of every frame')
        completed = True
        return monitor
    finally:
        processes.stop()
        if completed:  # a failed run keeps its node logs: its error names them
            shutil.rmtree(log_dir, ignore_errors=True)
        executor.shutdown()
        monitor.node.destroy_node()
        if context.ok():
            rclpy.shutdown(context=context)
        claim.release()
