"""Work done in the control loop's slack, after a tick's writes: side tasks.

A side task is a callable task(k) -> the tick at which it wants to be called next (> k); k is
the number of ticks done, so the newest log row is tick k - 1's. tipbot_fw.loop calls its one
side task in the tick it asked for, after the writes and the battery read, before it sleeps:
between two calls a side task costs the loop one integer comparison per tick. Side tasks never
touch the motors and never raise on a device of their own (lights, speaker, network).
"""


class SideTasks(object):
    """Two side tasks as one, each called in the tick it asked for (unrolled: this runs in the
    loop's slack every few ticks, and a loop over a list costs more there than the tasks' own
    bookkeeping)."""

    def __init__(self, first, second):
        self.first, self.second = first, second
        self.due_first = self.due_second = 1

    def __call__(self, k):
        if k >= self.due_first:
            self.due_first = self.first(k)
        if k >= self.due_second:
            self.due_second = self.second(k)
        return self.due_first if self.due_first < self.due_second else self.due_second


def combine(*tasks):
    """One side task doing all of `tasks` (None entries skipped); None if there are none."""
    tasks = [t for t in tasks if t is not None]
    if not tasks:
        return None
    task = tasks[0]
    for other in tasks[1:]:
        task = SideTasks(task, other)
    return task
