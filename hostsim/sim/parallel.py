"""Run independent simulations on the available cores, results in input order.

Every task carries its own seed, so the results do not depend on the number of workers
or on which worker ran what. Progress: a line on stderr every PROGRESS_EVERY_S (runs done of
all, the time left estimated from the pace so far), on a terminal or in a log. Ctrl-C: the
workers ignore it (no traceback from each of them), this process gets the KeyboardInterrupt and
the workers are ended at once.
"""
import os
import signal
import sys
import threading
import time
from concurrent.futures import ProcessPoolExecutor, as_completed

PROGRESS_EVERY_S = 10.0


def default_jobs():
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


class Progress(object):
    """'DESC: k/N done, T s so far, about L s left' on stderr every ``every_s`` while it runs,
    with a line when it starts and one when all is done: a phase that starts or ends between
    two ticks of the clock leaves no silence longer than every_s."""

    def __init__(self, total, desc, every_s=PROGRESS_EVERY_S, stream=None):
        self.total, self.desc, self.done, self.every_s = total, desc or "runs", 0, every_s
        self.stream = sys.stderr if stream is None else stream
        self.t0 = time.monotonic()
        self._say("%s: %d to do" % (self.desc, total))
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def line(self):
        elapsed = time.monotonic() - self.t0
        left = ", about %.0f s left" % (elapsed / self.done * (self.total - self.done)) if self.done else ""
        return "%s: %d/%d done, %.0f s so far%s" % (self.desc, self.done, self.total, elapsed, left)

    def _say(self, text):
        try:
            print(text, file=self.stream, flush=True)
            return True
        except (OSError, ValueError):
            return False

    def _run(self):
        while not self._stop.wait(self.every_s):
            if not self._say(self.line()):
                return

    def update(self, n=1):
        self.done += n

    def close(self):
        self._stop.set()
        if self.done == self.total:
            self._say("%s: %d/%d done in %.0f s" % (self.desc, self.done, self.total, time.monotonic() - self.t0))


def _ignore_sigint():
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def run_tasks(fn, tasks, jobs=None, desc=None, warm=None):
    """[fn(t) for t in tasks], on ``jobs`` processes (1: in this process).

    warm: a callable run once before forking (e.g. to generate the model cache that every
    worker would otherwise race to create).
    """
    jobs = default_jobs() if jobs is None else max(1, int(jobs))
    tasks = list(tasks)
    if warm is not None:
        warm()
    bar = Progress(len(tasks), desc)
    results = [None] * len(tasks)
    try:
        if jobs == 1 or len(tasks) <= 1:
            for i, t in enumerate(tasks):
                results[i] = fn(t)
                bar.update(1)
            return results
        pool = ProcessPoolExecutor(max_workers=min(jobs, len(tasks)), initializer=_ignore_sigint)
        try:
            futures = {pool.submit(fn, t): i for i, t in enumerate(tasks)}
            for fut in as_completed(futures):
                results[futures[fut]] = fut.result()
                bar.update(1)
        except BaseException:       # Ctrl-C, or a task's error: the other runs are not waited for
            for proc in list(getattr(pool, "_processes", {}).values()):
                proc.terminate()
            pool.shutdown(wait=False, cancel_futures=True)
            raise
        pool.shutdown()
        return results
    finally:
        bar.close()
