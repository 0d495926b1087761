"""Cost of the real tick code.

`python3 -m tipbot_fw.bench --ticks N [--gains FILE] [--bare] [--telemetry-every M]` runs the
control loop (tipbot_fw.loop, the same code as on the robot) for one start tick and N further
ticks against MemoryDevices and a virtual clock, as a supervised run does: the heartbeat store
in a shared page, the readings' plausibility checks, the log's rows written to a file in chunks
(tipbot_fw.record.container; the file is removed at the end), and the side task a run has in its
slack: the owner's cues (tipbot_fw.cues.LoopCues, without a brick: its checks, not the lights'
sysfs writes). ``--bare`` leaves the heartbeat page, the encoders' bound from the configuration
and the file out, to measure what they cost. With --telemetry-every, a telemetry datagram every M ticks goes to a UDP
socket of its own on 127.0.0.1 (the send's system call is the kernel's time, not counted). It
imports only tipbot_fw, numpy and the standard library (no ev3dev2), and does
the same start-up work for every N, so the instruction count of N ticks minus that of 0 ticks,
divided by N, is the cost of one tick including its log row. The fake devices and the clock
are C-level callables (bench_devices, FrozenClock), so what is counted is the firmware's own
work; the real device layer's reads and writes come on top (tipbot_fw.io.ev3dev). ``--whole``
counts what the brick pays for a tick: the same supervised loop with the real device layer on
plain files (FileDevices) and the real clock (MonotonicClock), its time reads and sleeps
included (the sleeps' kernel time is not instructions).
Without --gains it uses the repository's gains/physical.json (on the brick: `python3 -m
tipbot_fw bench`, with the deployed gains). `--device-layer` instead counts the real device
layer (tipbot_fw.io.ev3dev: 5 reads, 4 writes per tick) on plain files (FileDevices).

brick_bench() is the on-robot benchmark used by `python3 -m tipbot_fw bench`: the time of the
reads, the compute and the writes of a tick, the whole tick, and a verdict on the period.
"""
import collections
import itertools
import math
import os
import shutil
import socket
import sys
import tempfile
import time

import numpy as np

from tipbot_fw import side_tasks
from tipbot_fw.config import defaults
from tipbot_fw.cores.core import make_core
from tipbot_fw.cues import OwnerCues
from tipbot_fw.drive.pathfollow import follow_course
from tipbot_fw.drive.plan import drive_problem
from tipbot_fw.drive.remote import live_plan, remote_side
from tipbot_fw.gains import load_gains
from tipbot_fw.guard import heartbeat
from tipbot_fw.guard.plausibility import EncoderBound
from tipbot_fw.guard.safety import SafetyStop
from tipbot_fw.io.clock import MonotonicClock
from tipbot_fw.io.devices import MemoryDevices
from tipbot_fw.loop import ControlLoop
from tipbot_fw.record import logfile
from tipbot_fw.record.telemetry import TelemetrySender


def _readings(period=64):
    """Readings that move (soft-float arithmetic is cheaper on zeros) but stay well inside the
    fall and joint limits; th1 stays bounded because the gyro rate has zero mean."""
    table = []
    for k in range(period):
        s = math.sin(2.0 * math.pi * k / period)
        c = math.cos(2.0 * math.pi * k / period)
        table.append(((int(20 * s), int(-17 * s), int(9 * c), int(-5 * c)), (int(3 * s), int(10 * c))))
    return table


class FrozenClock(object):
    """Time stands still and sleeping is free (builtins, no Python frame): the bench counts the
    tick code, not a clock. The loop never sees a late tick."""
    now = float             # float() -> 0.0
    sleep_until = float     # float(t) -> t, discarded


def bench_devices():
    """MemoryDevices whose read_raw and write_duties are C-level callables (cycling through
    _readings(), keeping the last duties), so that the fake devices cost next to nothing."""
    dev = MemoryDevices(battery_v=8.0)
    dev.read_raw = itertools.cycle(_readings()).__next__
    dev.last_duties = collections.deque(maxlen=1)
    dev.write_duties = dev.last_duties.append
    return dev


# --drive: a course driven the whole run (forward and back, turning): a tick copies its row of
# the plan whatever the course (tipbot_fw.drive.plan), so any course costs the same.
BENCH_SEGMENT = [(0.02, math.radians(5.0), 1.0), (-0.02, math.radians(-5.0), 1.0)]
BENCH_REPEATS = 30


class _SteadyReceiver(object):
    """A remote's receiver that always has the same command (0.1 m/s, no turn): the bench's."""
    host = 'bench'

    def poll(self, now_s):
        return 0.1, 0.0


def run_memory(n_ticks, gains, bare=False, sender=None, whole=False, drive=False, follow=False,
               remote=False):
    """The loop for 1 + n_ticks ticks on bench_devices() and a FrozenClock, with the owner's cues
    (no brick) and `sender` (a TelemetrySender or None) in its slack -> (LoopStats, log). Unless
    bare: supervised (a heartbeat page), plausibility-checked, its log written to a temporary
    file (removed). whole: what the brick pays for a tick, the real device layer (FileDevices)
    and the real clock (MonotonicClock: its reads of the time and its sleeps) included; the
    overrun stop is off (an emulator may run a tick late). drive: a course's rows, made before the
    run (the tick's cost); follow: made in the slack as a run makes them, corrected from the
    robot's pose (tipbot_fw.drive.pathfollow: the tick's cost and the follower's, between ticks); remote:
    driven by a remote's live plan instead (tipbot_fw.drive.remote; a receiver that always has the same
    command: the plan's rows and the poll, between ticks)."""
    config = defaults()
    files = FileDevices.in_temporary_dir() if whole else None
    dev = files.devices if whole else bench_devices()
    core = make_core(gains, config, dev.counts_per_rot)
    core.set_gyro_bias(0.0)
    follower = live = None
    if remote:
        live = live_plan(gains, core)
    elif drive:
        # the same plan whatever n_ticks (tools/tick-cost subtracts a run of 0 ticks: making the
        # plan is start-up, not a tick's cost); a longer run holds its last row. Followed as a run
        # follows it: its rows made in the slack, corrected from the pose (tipbot_fw.drive.pathfollow)
        follower = follow_course(gains, core, BENCH_SEGMENT * BENCH_REPEATS, None if follow else n_ticks + 2)
    extra = {}
    writer = None
    if bare:
        log = logfile.LogBuffer(min(n_ticks + 1, config['log_max_rows']), core.rows)
    else:
        fd, path = tempfile.mkstemp(prefix='tipbot-bench-', suffix='.log')
        os.close(fd)
        writer = logfile.open_run_log(path, logfile.keep_plan(config['log_max_rows'], config['log_head_rows'],
                                                              n_ticks + 1), core.rows)
        os.unlink(path)
        writer.header({})
        log = logfile.LogBuffer.for_file(writer, core.rows)
        _, page, words = heartbeat.create_page()
        extra = dict(heartbeat=heartbeat.Heartbeat(words, os.getppid(), page),
                     encoder_bound=EncoderBound(config, dev.counts_per_rot, gains.ts_s))
    if whole:
        extra.update(max_lost_s=float('inf'), max_stall_s=float('inf'))
    else:
        extra.update(max_lost_s=config['limits']['max_lost_s'])
    # the bench's readings are no robot: the law saturates about two thirds of its ticks and the
    # files' encoders (--whole) stand still, which the saturation stop and the wheel watch would
    # end (the saturation count, once a chunk, is still paid and counted; the wheel watch too,
    # but for --whole)
    extra.update(max_saturated_s=float('inf'), watch_wheels=not whole)
    loop = ControlLoop(dev, core, MonotonicClock() if whole else FrozenClock(), log, gains.ts_s, 8.0,
                       battery_period_s=config['battery_period_s'],
                       overrun_window_s=config['limits']['overrun_window_s'],
                       duration_s=(n_ticks + 1) * gains.ts_s, realtime_priority=0, **extra)
    loop.side = side_tasks.combine(OwnerCues(streams=()).in_loop(loop, config['limits']['warn_battery_v']),
                              sender.attach(log, loop.stats, core) if sender else None,
                              follower.side() if follow else None,
                              remote_side(_SteadyReceiver(), live, gains.ts_s) if remote else None)
    try:
        stats = loop.run()
    finally:
        if files is not None:
            files.close()
    if writer is not None:
        log.count = stats.ticks
        log.flush()
        writer.close({})
    return stats, log


def local_sender(every):
    """A TelemetrySender to a UDP socket of this process on 127.0.0.1 (never read: the kernel
    drops what does not fit its buffer, the sends still succeed) -> (sender, socket)."""
    sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sink.bind(('127.0.0.1', 0))
    return TelemetrySender('127.0.0.1:{}'.format(sink.getsockname()[1]), every), sink


def _percentiles_ms(times_s):
    t = np.array(times_s) * 1e3
    return 'p50 {:.3f} ms, p99 {:.3f} ms, max {:.3f} ms'.format(
        np.percentile(t, 50), np.percentile(t, 99), np.max(t))


def _p(times_s, q):
    return float(np.percentile(np.array(times_s) * 1e3, q))


# A tick should leave this share of the period free: the kernel's threads (tacho and ADC
# interrupts, the gyro's kworker: ../shared/ev3-hardware.md) take CPU from the loop.
TICK_BUDGET = 0.8


def verdict(reads_s, compute_s, writes_s, ticks_s, overruns, period_s):
    """The owner's answer: does this brick keep the period? (lines to print)"""
    parts = [(_p(x, 50), _p(x, 99)) for x in (reads_s, compute_s, writes_s, ticks_s)]
    (r50, r99), (c50, c99), (w50, w99), (t50, t99) = parts
    budget = TICK_BUDGET * period_s * 1e3
    lines = ['a tick: reads {:.2f} + compute {:.2f} + writes {:.2f} = {:.2f} ms (p50), {:.2f} ms measured '
             '(p99 {:.2f} ms) of the {:g} ms period'.format(r50, c50, w50, r50 + c50 + w50, t50, t99,
                                                            period_s * 1e3)]
    if t99 <= budget and overruns == 0:
        lines.append('verdict: this brick keeps {:g} ms (p99 tick within {:.0f} % of the period)'.format(
            period_s * 1e3, 100 * TICK_BUDGET))
    else:
        lines.append('verdict: this brick does NOT keep {:g} ms (p99 tick {:.2f} ms > {:.2f} ms, {} overruns): '
                     'deploy the 10 ms gains: make deploy HOST=... DEPLOY_VARIANT=physical-ts0.010 '
                     '(docs/realistic-brick.md, "When the brick cannot keep 5 ms")'.format(period_s * 1e3, t99, budget, overruns))
    return lines


# Duties written by the on-robot bench instead of the controller's: alternating, every motor
# changes every time (4 writes, the worst case), and 1 % cannot move the robot.
_PATTERNS = ([1, 1, 1, 1], [0, 0, 0, 0])


class _PatternWrites(object):
    """Real reads, but _PATTERNS written instead of the controller's duties."""

    def __init__(self, devices):
        self.devices = devices
        self.counts_per_rot = devices.counts_per_rot
        self.read_raw = devices.read_raw
        self.read_battery_v = devices.read_battery_v
        self.stop_all = devices.stop_all
        self.k = 0

    def write_duties(self, duties):
        self.k ^= 1
        self.devices.write_duties(_PATTERNS[self.k])


def brick_bench(devices, gains, config, n_ticks, say=print):
    """Timings on the robot: read_raw, write_duties, the core's step, the whole loop tick, and
    whether the brick keeps the gains' period (verdict())."""
    now = time.monotonic
    try:
        reads = []
        for _ in range(n_ticks):
            t = now()
            enc, gyro = devices.read_raw()
            reads.append(now() - t)
        say('read_raw (5 reads):        ' + _percentiles_ms(reads))
        writes = []
        for k in range(n_ticks):
            t = now()
            devices.write_duties(_PATTERNS[k & 1])
            writes.append(now() - t)
        devices.stop_all()
        say('write_duties (4 writes):   ' + _percentiles_ms(writes))
        core = make_core(gains, config, devices.counts_per_rot)
        core.set_gyro_bias(float(gyro[1]))
        row = logfile.LogBuffer(1, core.rows).data
        core.set_battery(devices.read_battery_v())
        core.start(enc, gyro, row, 0)
        compute = []
        for _ in range(n_ticks):
            t = now()
            core.step(enc, gyro, row, 0)
            compute.append(now() - t)
        say('core step (compute):       ' + _percentiles_ms(compute))
        wrapped = _PatternWrites(devices)
        core = make_core(gains, config, devices.counts_per_rot)
        core.set_gyro_bias(float(gyro[1]))
        log = logfile.LogBuffer(n_ticks, core.rows)
        loop = ControlLoop(wrapped, core, MonotonicClock(), log, gains.ts_s,
                           devices.read_battery_v(), duration_s=n_ticks * gains.ts_s,
                           max_lost_s=float('inf'),
                           realtime_priority=config['realtime_priority'])
        try:
            stats = loop.run()
        except SafetyStop as e:
            say('loop stopped early: {}'.format(e))
            stats = loop.stats
        _, rows = log.ordered()
        ticks = rows[:, core.rows.col('tick_s')]
        say('loop tick (read..write):   ' + _percentiles_ms(ticks))
        say('overruns: {} of {} ticks, SCHED_FIFO: {}'.format(
            stats.overruns, stats.ticks, stats.realtime))
        for line in verdict(reads, compute, writes, ticks, stats.overruns, gains.ts_s):
            say(line)
    finally:
        devices.stop_all()


# The repository's gains, used when --gains is not given and they exist (as under `make bench`).
REPO_GAINS = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                          'gains', 'physical.json')


class FileDevices(object):
    """tipbot_fw.io.ev3dev.Ev3Devices on plain files laid out as the sysfs attributes it opens, for
    counting the device layer's own instructions per tick (python-ev3dev2's discovery is
    skipped: the virtual brick has no ev3dev2, and discovery is not part of a tick)."""

    def __init__(self, root):
        from tipbot_fw.config import defaults as config_defaults
        from tipbot_fw.io.ev3dev import BATTERY_PATH, Ev3Devices, SysfsDevices, device_spec
        config = config_defaults()
        motors, gyro, stop_action = device_spec(config)
        paths = {}
        for port, value in [(p, b'1234\n') for p, _ in motors] + [(gyro[0], b'\x05\x00\xfd\xff')]:
            d = os.path.join(root, port)
            os.makedirs(d)
            paths[port] = d
            for name in ('position', 'duty_cycle_sp', 'command', 'stop_action', 'polarity', 'mode'):
                with open(os.path.join(d, name), 'wb') as f:
                    f.write(value if name == 'position' else b'')
            with open(os.path.join(d, 'bin_data'), 'wb') as f:
                f.write(value)
        os.makedirs(os.path.dirname(os.path.join(root, BATTERY_PATH)))
        with open(os.path.join(root, BATTERY_PATH), 'wb') as f:
            f.write(b'8000000\n')
        dev = Ev3Devices.__new__(Ev3Devices)
        SysfsDevices.__init__(dev)
        dev._duty_fds, dev._cmd_fds, dev._last = (), (), [0, 0, 0, 0]
        dev._motor_ports = tuple(p for p, _ in motors)
        dev._gyro_port = gyro[0]
        dev._ir, dev._ir_fd = None, -1
        dev.paths, dev.counts_per_rot = paths, (360, 360, 360, 360)
        dev._open(root)
        dev._set_up(stop_action)
        self.devices = dev
        self.root = None

    @classmethod
    def in_temporary_dir(cls):
        """FileDevices on files in a new temporary directory, removed by close()."""
        root = tempfile.mkdtemp(prefix='tipbot-bench-')
        files = cls(root)
        files.root = root
        return files

    def close(self):
        self.devices.close()
        if self.root is not None:
            shutil.rmtree(self.root, ignore_errors=True)


def run_device_layer(n_ticks):
    """n_ticks of one read_raw and one write_duties that changes all four duties (the worst
    case) on FileDevices: the device layer's cost per tick, beside the tick's own."""
    files = FileDevices.in_temporary_dir()
    dev = files.devices
    read, write = dev.read_raw, dev.write_duties
    a, b = _PATTERNS
    try:
        for _ in range(n_ticks // 2):
            read()
            write(a)
            read()
            write(b)
    finally:
        files.close()


def main(argv=None):
    args = sys.argv[1:] if argv is None else argv
    n_ticks = None
    gains_path = None
    device_layer = False
    bare = False
    whole = False
    drive = follow = remote = False
    every = None
    usage = ('usage: python3 -m tipbot_fw.bench --ticks N [--gains FILE] [--bare | --whole] [--telemetry-every M] '
             '[--device-layer] [--drive [--follow] | --remote]')
    while args:
        if args[0] in ('--bare', '--device-layer', '--whole', '--drive', '--follow', '--remote'):
            bare = bare or args[0] == '--bare'
            device_layer = device_layer or args[0] == '--device-layer'
            whole = whole or args[0] == '--whole'
            drive = drive or args[0] == '--drive'
            follow = follow or args[0] == '--follow'
            remote = remote or args[0] == '--remote'
            args = args[1:]
            continue
        if args[0] == '--ticks' and len(args) > 1 and args[1].isdigit():
            n_ticks = int(args[1])
        elif args[0] == '--gains' and len(args) > 1:
            gains_path = args[1]
        elif args[0] == '--telemetry-every' and len(args) > 1 and args[1].isdigit() and int(args[1]) > 0:
            every = int(args[1])
        else:
            sys.stderr.write(usage + '\n')
            return 2
        args = args[2:]
    if n_ticks is None or (whole and bare) or (follow and not drive):
        sys.stderr.write(usage + '\n')
        return 2
    if device_layer:
        run_device_layer(n_ticks)
        sys.stdout.write('device layer: {} ticks of 5 reads and 4 writes on files\n'.format(n_ticks))
        return 0
    if gains_path is None and os.path.isfile(REPO_GAINS):
        gains_path = REPO_GAINS
    if gains_path is None:
        sys.stderr.write('bench: no gains: give --gains FILE (the repository has none at {})\n'.format(REPO_GAINS))
        return 2
    gains = load_gains(gains_path)
    if (drive or remote) and drive_problem(gains, defaults()):
        sys.stderr.write('bench: --drive: {}\n'.format(drive_problem(gains, defaults())))
        return 2
    sender, sink = local_sender(every) if every else (None, None)
    stats, _ = run_memory(n_ticks, gains, bare, sender, whole, drive, follow, remote)
    if stats.ticks != n_ticks + 1:
        sys.stderr.write('bench: the loop stopped after {} ticks\n'.format(stats.ticks))
        return 1
    sys.stdout.write('ticks {} (+1 start tick), gains {}{}{}\n'.format(
        n_ticks, gains_path, ', bare (no heartbeat, plausibility or log file)' if bare else
        ', whole (the device layer on files and the real clock)' if whole else '',
        ', driving a course' + (', followed in the plane' if follow else '') if drive else
        ', driven by a remote' if remote else ''))
    if sender is not None:
        ts_s = gains.ts_s
        sys.stdout.write('telemetry: {} datagrams of {} bytes in {} ticks (one every {}: {:.0f} per second at '
                         '{:g} ms), {} not sent\n'.format(sender.sent, sender.size, n_ticks + 1, every,
                                                         1.0 / (every * ts_s), ts_s * 1e3, sender.errors))
        sender.close()
        sink.close()
    return 0


if __name__ == '__main__':
    sys.exit(main())
