"""A single background worker per node: heavy work off the executor, in arrival order."""

import queue
import threading


class OrderedWorker:
    """Run submitted jobs one at a time, first in first out, on a daemon thread.

    One thread and one queue keep the outputs in input order (determinism: docs/design.md
    section 4) while the executor's callbacks return at once. ``on_error(job, error)`` is called
    for a job that raises, and the worker carries on with the next one.
    """

    def __init__(self, name, on_error):
        self._jobs = queue.Queue()
        self._on_error = on_error
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self._thread.start()

    def submit(self, job):
        """Queue a callable to run after every job submitted before it."""
        self._jobs.put(job)

    def idle(self):
        """Return True when no job is queued or running."""
        return self._jobs.unfinished_tasks == 0

    def stop(self, timeout=10.0):
        """Finish the queued jobs, then stop the thread."""
        self._jobs.put(None)
        self._thread.join(timeout)

    def _loop(self):
        while True:
            job = self._jobs.get()
            try:
                if job is None:
                    return
                job()
            except Exception as error:  # noqa: BLE001  a bad window must not kill the node
                self._on_error(job, error)
            finally:
                self._jobs.task_done()
