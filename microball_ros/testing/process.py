"""A node's console script as a process: parameters in, ready in the graph, stopped cleanly.

``NodeProcess('camera_tracker', {'meters_per_pixel': 5e-6})`` starts the console script (from
the running Python's environment first, then PATH) with its parameters in a params file
(``--params-file``) and any ``-p`` values given as ``ros_args``; its standard output and error
go to one log file. ``wait_until_ready`` spins a Harness until a condition holds (by default
the node is in the ROS graph), failing at once with the log if the process exits. ``stop``
sends SIGINT, waits up to a deadline, then SIGKILLs; the exit code and log stay available.
The child inherits this process's environment (the test session's ROS domain and the lock-step
Fast DDS profile) and gets SIGTERM if the test process dies (Linux parent-death signal).
"""

import ctypes
import os
import shutil
import signal
import subprocess
import sys
import tempfile

import yaml

_PR_SET_PDEATHSIG = 1


_PROFILES = ('<?xml version="1.0" encoding="UTF-8"?>\n'
             '<profiles xmlns="http://www.eprosima.com">\n</profiles>\n')
# Loopback UDP only: no shared memory, nothing sent beyond this machine.
_LOOPBACK_ONLY = """  <transport_descriptors>
    <transport_descriptor>
      <transport_id>microball_loopback_udp</transport_id>
      <type>UDPv4</type>
      <interfaceWhiteList><address>127.0.0.1</address></interfaceWhiteList>
    </transport_descriptor>
  </transport_descriptors>
  <participant profile_name="microball_killable" is_default_profile="true">
    <rtps>
      <useBuiltinTransports>false</useBuiltinTransports>
      <userTransports><transport_id>microball_loopback_udp</transport_id></userTransports>
      <builtin>
        <initialPeersList>
          <locator><udpv4><address>127.0.0.1</address></udpv4></locator>
        </initialPeersList>
      </builtin>
    </rtps>
  </participant>
"""


def killable_env(directory, base=None):
    """Return a copy of ``base`` (os.environ) for a node a test will SIGKILL: no shared memory.

    A Fast DDS participant killed with SIGKILL leaves its shared-memory ports behind, and the
    next participant to open one of them (a restarted node) removes it as a zombie while the
    processes that were sending to the killed one still have it mapped: they go on writing to
    a deleted segment and can crash (eProsima/Fast-DDS#4728; our CI saw a segfault in
    destroy_node after a killed node's restart). Under ``ROS_AUTOMATIC_DISCOVERY_RANGE=
    LOCALHOST`` rmw_fastrtps always adds the shared-memory transport, so this node's range is
    ``SYSTEM_DEFAULT`` (rmw leaves the transports alone) with a Fast DDS profile, written to
    ``directory``, that gives it UDP on 127.0.0.1 only and localhost as its initial peer: it
    still talks to nothing beyond this machine, and the other processes reach it over
    loopback. The profile keeps what the inherited one (the lock-step profile) holds.
    """
    env = dict(os.environ if base is None else base)
    inherited = env.get('FASTDDS_DEFAULT_PROFILES_FILE')
    text = _PROFILES
    if inherited and os.path.isfile(inherited):
        with open(inherited) as handle:
            text = handle.read()
    path = os.path.join(directory, 'fastdds_killable.xml')
    with open(path, 'w') as handle:
        handle.write(text.replace('</profiles>', _LOOPBACK_ONLY + '</profiles>'))
    env['FASTDDS_DEFAULT_PROFILES_FILE'] = path
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'SYSTEM_DEFAULT'
    return env


class NodeExited(AssertionError):
    """A node process exited while the test needed it running."""


def _die_with_parent():  # runs in the child, between fork and exec
    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)


def find_executable(name):
    """Return the path of console script ``name``: beside sys.executable first, then PATH."""
    if os.sep in name:
        return name
    beside = os.path.join(os.path.dirname(sys.executable), name)
    if os.access(beside, os.X_OK):
        return beside
    found = shutil.which(name)
    if found is None:
        raise FileNotFoundError(f'no console script {name!r} next to {sys.executable} or on '
                                'PATH (is the package installed in this environment?)')
    return found


def _read(path):
    try:
        with open(path, errors='replace') as handle:
            return handle.read()
    except FileNotFoundError:
        return ''


class NodeProcess:
    """One node executable run as a child process.

    ``executable``: a console script name (or path), or an argv list used as it is.
    ``parameters``: a mapping written to a params file (``/**: ros__parameters``).
    ``params_file``: a params file of your own (after the generated one, so it wins).
    ``ros_args``: more arguments after ``--ros-args`` (e.g. ``['-p', 'epsilon:=0.1']``).
    ``name``: the node's name in the graph (default: the executable's name).
    ``log_dir``: where the params file and ``<name>.log`` go (default: a new temp folder).
    ``merge_output``: standard output into the log too (default); False keeps it apart in
    ``<name>.stdout.log`` (``stdout``), so the log is exactly standard error (ROS logging).
    """

    def __init__(self, executable, parameters=None, *, params_file=None, ros_args=(),
                 args=(), name=None, namespace='/', log_dir=None, env=None,
                 merge_output=True):
        argv = list(executable) if isinstance(executable, (list, tuple)) else [executable]
        self.name = name or os.path.basename(argv[0])
        self.namespace = namespace
        self.argv = [find_executable(argv[0]) if len(argv) == 1 else argv[0], *argv[1:],
                     *args]
        self.parameters = dict(parameters or {})
        self.params_file = params_file
        self.ros_args = list(ros_args)
        self.log_dir = str(log_dir) if log_dir else tempfile.mkdtemp(prefix='microball-node-')
        self.log_path = os.path.join(self.log_dir, f'{self.name}.log')
        self.stdout_path = None if merge_output else os.path.join(
            self.log_dir, f'{self.name}.stdout.log')
        self.env = dict(os.environ if env is None else env)
        self.env.setdefault('PYTHONUNBUFFERED', '1')
        self.returncode = None
        self.killed = False
        self._process = None

    @property
    def command(self):
        """Return the full command line."""
        command, ros_args = list(self.argv), []
        if self.parameters:  # the generated file first, so the user's params_file wins
            ros_args += ['--params-file', os.path.join(self.log_dir, f'{self.name}.params.yaml')]
        if self.params_file:
            ros_args += ['--params-file', str(self.params_file)]
        ros_args += self.ros_args
        return command + (['--ros-args', *ros_args] if ros_args else [])

    @property
    def pid(self):
        """Return the process id (None before start)."""
        return None if self._process is None else self._process.pid

    def start(self):
        """Write the params file and start the process; return self."""
        if self._process is not None:
            raise RuntimeError(f'{self.name} was started already')
        os.makedirs(self.log_dir, exist_ok=True)
        if self.parameters:
            with open(os.path.join(self.log_dir, f'{self.name}.params.yaml'), 'w') as handle:
                yaml.safe_dump({'/**': {'ros__parameters': self.parameters}}, handle)
        with open(self.log_path, 'w') as log, \
                open(self.stdout_path or os.devnull, 'w') as stdout:
            self._process = subprocess.Popen(
                self.command, stdout=stdout if self.stdout_path else log, stderr=log,
                stdin=subprocess.DEVNULL, env=self.env, preexec_fn=_die_with_parent)
        return self

    def poll(self):
        """Return the exit code if the process has exited, else None."""
        if self._process is not None and self.returncode is None:
            self.returncode = self._process.poll()
        return self.returncode

    @property
    def running(self):
        """Return True while the process runs."""
        return self._process is not None and self.poll() is None

    @property
    def log(self):
        """Return what the process wrote so far to standard error (and output, if merged)."""
        return _read(self.log_path)

    @property
    def stdout(self):
        """Return the standard output kept apart (merge_output=False), else ''."""
        return _read(self.stdout_path) if self.stdout_path else ''

    def log_tail(self, lines=20):
        """Return the last ``lines`` lines of the log."""
        return '\n'.join(self.log.rstrip().splitlines()[-lines:]) or '(no output)'

    def check(self):
        """Raise NodeExited (with the log's tail) if the process has exited."""
        code = self.poll()
        if code is not None:
            raise NodeExited(f'node {self.name} exited with code {code}; its log '
                             f'({self.log_path}) ends:\n{self.log_tail()}')

    def wait_until_ready(self, harness, ready=None, timeout=30.0):
        """Spin ``harness`` until ``ready()`` (default: the node is in the graph); return self.

        Fails with NodeExited as soon as the process exits, or AssertionError at the deadline.
        """
        harness.watch(self)
        if ready is None:
            harness.wait_for_node(self.name, self.namespace, timeout)
        else:
            harness.spin_until(ready, timeout, f'{self.name} to be ready')
        return self

    def send_signal(self, sig):
        """Send a signal to the process if it still runs."""
        if self.running:
            self._process.send_signal(sig)

    def stop(self, timeout=10.0, sig=signal.SIGINT):
        """Send ``sig`` (SIGINT), wait up to ``timeout`` s, then SIGKILL; return the exit code.

        ``sig=None`` sends nothing first: it waits for a process that is to exit by itself.
        """
        if self._process is None:
            return None
        if self.poll() is None:
            if sig is not None:
                self._process.send_signal(sig)
            try:
                self._process.wait(timeout)
            except subprocess.TimeoutExpired:
                self.killed = True
                self._process.kill()
                self._process.wait()
        self.returncode = self._process.returncode
        return self.returncode

    def __enter__(self):
        return self.start() if self._process is None else self

    def __exit__(self, *exc):
        self.stop()
