"""The terminal side of the commands: progress lines, and the space bar that pauses play.

``Progress`` shows a command's progress on stderr without ever letting a progress line precede
a quick error; ``pause_on_space`` reads the space bar while ``microball play`` runs.
"""

import sys
import termios
import threading
import tty


class Progress:
    """Progress lines on stderr, held back a moment so that none precedes a quick error.

    A line is printed when the next one arrives or after HOLD seconds (a timer); a line still
    pending when the command ends is dropped: on success the results say it, on failure the
    error is the only line the user sees.
    """

    HOLD = 0.5

    def __init__(self):
        self._pending = None
        self._last = None
        self._timer = None
        self._lock = threading.Lock()

    def __call__(self, message):
        """Show a progress line (after the previous one, if it is still pending)."""
        with self._lock:
            if message == self._last:  # nothing new to say (a stalled count)
                return
            self._last = message
            self._flush_locked()
            self._pending = message
            self._timer = threading.Timer(self.HOLD, self.flush)
            self._timer.daemon = True
            self._timer.start()

    def _flush_locked(self):
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if self._pending is not None:
            print(self._pending, file=sys.stderr, flush=True)
            self._pending = None

    def flush(self):
        """Print the pending line now."""
        with self._lock:
            self._flush_locked()

    def drop(self):
        """Forget the pending line (the command failed: its error says what happened)."""
        with self._lock:
            if self._timer is not None:
                self._timer.cancel()
            self._pending = self._timer = None


def pause_on_space(progress):
    """Return (paused, restore) for the space bar when stdin is a terminal, else (None, None).

    ``progress(line)`` is told when play pauses or resumes.

    paused() is toggled by each space typed; restore() puts the terminal back as it was (it is
    switched to character mode while playing).
    """
    stdin = sys.stdin
    if not stdin.isatty():
        return None, None
    state = {'paused': False}
    fd = stdin.fileno()
    saved = termios.tcgetattr(fd)
    tty.setcbreak(fd)

    def read_keys():
        while True:
            try:
                key = stdin.read(1)
            except (OSError, ValueError):  # the terminal went away or was closed
                return
            if not key:
                return
            if key == ' ':
                state['paused'] = not state['paused']
                progress('paused (space resumes)' if state['paused'] else 'resumed')

    threading.Thread(target=read_keys, daemon=True).start()
    return (lambda: state['paused'],
            lambda: termios.tcsetattr(fd, termios.TCSADRAIN, saved))
