"""Never mix rigs: a ROS domain of one's own, and the checks that catch a foreign publisher.

Every ``microball experiment`` (and every test session) claims a ROS domain ID that no other
microball run on this machine holds: a lock file per ID in ``LOCK_DIR`` (machine-wide, as a
ROS domain is: not the temp directory, which ``TMPDIR`` or a test can point elsewhere; two
test runs at once each ran an experiment on the same domain that way), held with ``flock``
for the life of the run, so a crashed run frees its ID at once. Discovery is kept to
this machine (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``) unless the user chose otherwise.
Another rig on the network that joins the same domain anyway (a fixed ID, another machine,
another tool) is caught by ``ForeignPublisherCheck``: more publishers on a topic than the run
started, or a topic's sequence (frame index, stamps) going backwards.
"""

from dataclasses import dataclass
import fcntl
import os
import tempfile

from microball_ros.core.errors import MicroballError

# Domain IDs 1..101 are usable with Fast DDS's default ports on Linux; 0 is everybody's default.
DOMAIN_IDS = range(1, 102)
LOCK_DIR = '/tmp'  # the domain locks' folder, one for the machine (the temp folder if absent)


class IsolationError(MicroballError):
    """Another run or rig shares this run's ROS domain; its data would be mixed with ours."""


@dataclass
class DomainClaim:
    """A ROS domain ID held for this process (release() or process exit frees it)."""

    domain_id: int
    handle: object

    def environment(self, base=None):
        """Return a copy of ``base`` (os.environ) set to run nodes in this domain only."""
        env = dict(os.environ if base is None else base)
        env['ROS_DOMAIN_ID'] = str(self.domain_id)
        env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
        return env

    def release(self):
        """Free the domain ID for other runs."""
        if self.handle is not None:
            self.handle.close()
            self.handle = None


def _lock_path(domain_id):
    folder = LOCK_DIR if os.path.isdir(LOCK_DIR) else tempfile.gettempdir()
    return os.path.join(folder, f'microball-ros-domain-{domain_id}.lock')


def _try_lock(domain_id):
    try:
        handle = open(_lock_path(domain_id), 'a')
    except PermissionError:  # another user's lock file (their run holds it, or held it)
        return None
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        handle.close()
        return None
    return handle


def claim_domain(domain_id=None):
    """Claim ``domain_id``, or the lowest free one; raise IsolationError if none is free.

    A domain ID given by the user that another microball run on this machine holds is refused
    (IsolationError) rather than shared.
    """
    if domain_id is not None:
        if domain_id not in DOMAIN_IDS:
            raise IsolationError(f'ROS domain ID {domain_id} is outside '
                                 f'{DOMAIN_IDS.start}..{DOMAIN_IDS.stop - 1}')
        handle = _try_lock(domain_id)
        if handle is None:
            raise IsolationError(f'ROS domain {domain_id} is in use by another microball run '
                                 'on this machine; choose another or leave it to be chosen')
        return DomainClaim(domain_id, handle)
    for candidate in DOMAIN_IDS:
        handle = _try_lock(candidate)
        if handle is not None:
            return DomainClaim(candidate, handle)
    raise IsolationError('no free ROS domain ID on this machine (all of 1..101 are held)')


class ForeignPublisherCheck:
    """Say when a topic has more publishers than expected or its sequence goes backwards.

    ``expected`` maps topic -> the number of publishers this run started on it. ``observe``
    takes each message's topic and its sequence key (frame index, or stamp in ns); ``check``
    is given the graph's publisher counts. Both return a one-line problem or None; the first
    problem is kept in ``problem``.
    """

    def __init__(self, expected):
        self.expected = dict(expected)
        self._last = {}
        self.backwards = dict.fromkeys(self.expected, 0)
        self.problem = None

    def _report(self, text):
        if self.problem is None:
            self.problem = text
        return text

    def observe(self, topic, key):
        """Record one message's sequence key; return a problem if it went backwards."""
        last = self._last.get(topic)
        self._last[topic] = key
        if last is not None and key <= last:
            self.backwards[topic] = self.backwards.get(topic, 0) + 1
            return self._report(
                f'{topic}: sequence went backwards ({key} after {last}): another rig is '
                'publishing on this ROS domain')
        return None

    def check(self, publisher_counts):
        """Compare topic -> publisher count with the expected counts; return a problem."""
        for topic, count in publisher_counts.items():
            expected = self.expected.get(topic)
            if expected is not None and count > expected:
                return self._report(
                    f'{topic}: {count} publishers where this run started {expected}: another '
                    'rig is publishing on this ROS domain')
        return None
