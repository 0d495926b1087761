"""Work done in the control loop's slack, after a tick's writes: side tasks.

A side task is a callable task(k) -> the tick at which it wants to be called next (> k); k is
the number of ticks done, so the newest log row is tick k - 1's. tipbot_fw.loop calls its one
side task after the writes, the log's chunk and the battery read, before it sleeps, in the
first tick from the one it asked for that leaves enough slack (loop.SLACK_S): a call may come
a few ticks late, and early only after a tick that skipped whole periods (a stall: a drive's
live plan must make the rows the skip took: the cues and the drives check their own due
ticks, telemetry sends the newest row once more).
Between two calls a side task costs the loop one integer comparison per tick. Side tasks never touch the motors and never raise on a device of their
own (lights, speaker, network).
"""


def both(first, second):
    """Two side tasks as one, each called in the tick it asked for. A closure over locals: it
    runs in the slack every few ticks, where attribute lookups cost on the brick."""
    due = [1, 1]

    def task(k):
        first_due, second_due = due
        if k >= first_due:
            due[0] = first_due = first(k)
        if k >= second_due:
            due[1] = second_due = second(k)
        return first_due if first_due < second_due else second_due
    return task


def combine(*tasks):
    """One side task doing all of `tasks` (None entries skipped); None if there are none."""
    tasks = [t for t in tasks if t is not None]
    if not tasks:
        return None
    task = tasks[0]
    for other in tasks[1:]:
        task = both(task, other)
    return task
