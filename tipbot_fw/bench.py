"""Cost of the real tick code.

`python3 -m tipbot_fw.bench --ticks N [--gains FILE] [--bare] [--telemetry-every M]` runs the
control loop (tipbot_fw.loop, the same code as on the robot) for one start tick and N further
ticks against MemoryDevices and a virtual clock, as a supervised run does: the heartbeat store
in a shared page, the readings' plausibility checks, the log's rows written to a file in chunks
(tipbot_fw.logcontainer; the file is removed at the end), and the side task a run has in its
slack: the owner's cues (tipbot_fw.cues.LoopCues, without a brick: its checks, not the lights'
sysfs writes). ``--bare`` leaves the heartbeat page, the encoders' bound from the configuration
and the file out, to measure what they cost. With --telemetry-every, a telemetry datagram every M ticks goes to a UDP
socket of its own on 127.0.0.1 (the send's system call is the kernel's time, not counted). It
imports only tipbot_fw, numpy and the standard library (no ev3dev2), and does
the same start-up work for every N, so the instruction count of N ticks minus that of 0 ticks,
divided by N, is the cost of one tick including its log row. The fake devices and the clock
are C-level callables (bench_devices, FrozenClock), so what is counted is the firmware's own
work; the real device layer's reads and writes come on top (tipbot_fw.ev3io).
Without --gains it uses the repository's gains/physical.json when there is one, else synthetic
gains with the structure of the real ones.

brick_bench() is the on-robot benchmark used by `python3 -m tipbot_fw bench`.
"""
import collections
import itertools
import math
import os
import socket
import sys
import tempfile
import time

import numpy as np

from tipbot_fw import heartbeat, logfile, slack
from tipbot_fw.clock import MonotonicClock
from tipbot_fw.config import defaults, motor_polarity
from tipbot_fw.core import Core
from tipbot_fw.cues import OwnerCues
from tipbot_fw.devices import MemoryDevices
from tipbot_fw.gains import ACTUATED_INPUTS, N_INPUTS, UNUSED_INPUT, gains_from_dict, load_gains
from tipbot_fw.loop import ControlLoop
from tipbot_fw.plausibility import EncoderBound
from tipbot_fw.safety import SafetyStop
from tipbot_fw.telemetry import SIZE, TelemetrySender


def synthetic_gains_doc(A, B, K, ts_s, Q=None, R=None, u_max_v=7.6, detector_pole=0.2,
                        state_units=None, model_variant='physical', generator='synthetic', **extra):
    """A schema-1 gains document around a model (A, B) and a stabilizing gain K (SI): the detector
    of Section 6 with G_w = B_a^+ (so L2 = E G_w projects on range(E): (L2 C - I) E = 0),
    L1 = Abar - detector_pole I (so Abar - L1 C = detector_pole I), and K_w = I on the actuated
    inputs (it cancels an input disturbance). extra: further fields (parameters, ...)."""
    n = A.shape[0]
    Ba = B[:, ACTUATED_INPUTS]
    G = np.zeros((N_INPUTS, n))
    G[ACTUATED_INPUTS, :] = np.linalg.pinv(Ba)
    L2 = Ba.dot(G[ACTUATED_INPUTS, :])
    L1 = (np.eye(n) - L2).dot(A) - detector_pole * np.eye(n)
    K_w = np.diag([0.0 if i == UNUSED_INPUT else 1.0 for i in range(N_INPUTS)])
    rho = float(np.max(np.abs(np.linalg.eigvals(A - B.dot(K)))))
    doc = {
        'schema_version': 1, 'model_variant': model_variant, 'ts_s': ts_s,
        'state_names': list(logfile.STATE_NAMES),
        'state_units': list(logfile.STATE_UNITS if state_units is None else state_units),
        'input_names': ['u_r', 'u_l', 'u_th1', 'u_th2', 'u_th3'], 'input_units': ['V'] * N_INPUTS,
        'actuated_inputs': list(ACTUATED_INPUTS),
        'A': A.tolist(), 'B': B.tolist(), 'C': np.eye(n).tolist(), 'E': B.tolist(),
        'K': K.tolist(), 'K_w': K_w.tolist(), 'L1': L1.tolist(), 'L2': L2.tolist(),
        'G_w': G.tolist(), 'detector_eigenvalues': [detector_pole] * n, 'closed_loop_spectral_radius': rho,
        'Q': (np.eye(n) if Q is None else Q).tolist(), 'R': (np.eye(N_INPUTS) if R is None else R).tolist(),
        'u_max_v': u_max_v, 'parameters': {}, 'parameters_sha256': '', 'model_options': {},
        'generator': generator,
    }
    doc.update(extra)
    return doc


def synthetic_gains(ts_s=0.005, seed=1):
    """Valid gains with the structure of the real ones (synthetic_gains_doc) for a random
    robot-like model; K from a few hundred Riccati iterations (Q = I, R = I): stabilizing, with
    values like an LQR's, and no scipy (this runs on the brick)."""
    rng = np.random.RandomState(seed)
    n = 10
    A = np.eye(n) + ts_s * np.vstack([np.hstack([np.zeros((5, 5)), np.eye(5)]),
                                      rng.uniform(-2.0, 2.0, (5, 10))])
    B = np.zeros((n, 5))
    B[5:, ACTUATED_INPUTS] = ts_s * rng.uniform(-20.0, 20.0, (5, 4))
    Ba = B[:, ACTUATED_INPUTS]
    P = np.eye(n)
    for _ in range(300):
        Ka = np.linalg.solve(np.eye(4) + Ba.T.dot(P).dot(Ba), Ba.T.dot(P).dot(A))
        P = np.eye(n) + A.T.dot(P).dot(A - Ba.dot(Ka))
    K = np.zeros((5, n))
    K[ACTUATED_INPUTS, :] = Ka
    doc = synthetic_gains_doc(A, B, K, ts_s, generator='tipbot_fw.bench.synthetic_gains')
    return gains_from_dict(doc, '<synthetic>', 'synthetic')


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


def run_memory(n_ticks, gains=None, bare=False, sender=None):
    """The loop for 1 + n_ticks ticks on bench_devices() and a FrozenClock, with the owner's cues
    (no brick) and `sender` (a TelemetrySender or None) in its slack -> (LoopStats, log). Unless
    bare: supervised (a heartbeat page), plausibility-checked, its log written to a temporary
    file (removed)."""
    config = defaults()
    if gains is None:
        gains = synthetic_gains()
    dev = bench_devices()
    core = Core(gains, config, 0.0, dev.counts_per_rot)
    extra = {}
    writer = None
    if bare:
        log = logfile.LogBuffer(min(n_ticks + 1, config['log_max_rows']))
    else:
        fd, path = tempfile.mkstemp(prefix='tipbot-bench-', suffix='.log')
        os.close(fd)
        writer = logfile.open_run_log(path, n_ticks + 1)
        os.unlink(path)
        writer.header({})
        log = logfile.LogBuffer.for_file(writer, (1, 1, 1, 1), config['log_max_rows'])
        _, page, words = heartbeat.create_page()
        extra = dict(heartbeat=heartbeat.Heartbeat(words, os.getppid(), page),
                     encoder_bound=EncoderBound(config, dev.counts_per_rot, gains.ts_s))
    loop = ControlLoop(dev, core, FrozenClock(), log, gains.ts_s, 8.0,
                       battery_period_s=config['battery_period_s'],
                       max_consecutive_overruns=config['limits']['max_consecutive_overruns'],
                       duration_s=(n_ticks + 1) * gains.ts_s, realtime_priority=0, **extra)
    loop.side = slack.combine(OwnerCues(streams=()).in_loop(loop, config['limits']['warn_battery_v']),
                              sender.attach(log, loop.stats, motor_polarity(config)) if sender else None)
    stats = loop.run()
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
    """Timings on the robot: read_raw, write_duties, Core.step, and the whole loop tick."""
    now = time.monotonic
    try:
        times = []
        for _ in range(n_ticks):
            t = now()
            enc, gyro = devices.read_raw()
            times.append(now() - t)
        say('read_raw (5 reads):        ' + _percentiles_ms(times))
        times = []
        for k in range(n_ticks):
            t = now()
            devices.write_duties(_PATTERNS[k & 1])
            times.append(now() - t)
        devices.stop_all()
        say('write_duties (4 writes):   ' + _percentiles_ms(times))
        core = Core(gains, config, 0.0, devices.counts_per_rot)
        row = logfile.LogBuffer(1).data
        core.set_battery(8.0)
        core.start(enc, gyro, row, 0)
        times = []
        for _ in range(n_ticks):
            t = now()
            core.step(enc, gyro, row, 0)
            times.append(now() - t)
        say('Core.step (compute):       ' + _percentiles_ms(times))
        wrapped = _PatternWrites(devices)
        core = Core(gains, config, float(gyro[1]), devices.counts_per_rot)
        log = logfile.LogBuffer(n_ticks)
        loop = ControlLoop(wrapped, core, MonotonicClock(), log, gains.ts_s,
                           devices.read_battery_v(), duration_s=n_ticks * gains.ts_s,
                           max_consecutive_overruns=10 ** 6,
                           realtime_priority=config['realtime_priority'])
        try:
            stats = loop.run()
        except SafetyStop as e:
            say('loop stopped early: {}'.format(e))
            stats = loop.stats
        _, rows = log.ordered((1, 1, 1, 1))
        say('loop tick (read..write):   ' + _percentiles_ms(rows[:, logfile.TICK]))
        say('overruns: {} of {} ticks, SCHED_FIFO: {}'.format(
            stats.overruns, stats.ticks, stats.realtime))
    finally:
        devices.stop_all()


# The repository's gains, used when --gains is not given and they exist (as under `make bench`).
REPO_GAINS = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                          'gains', 'physical.json')


def main(argv=None):
    args = sys.argv[1:] if argv is None else argv
    n_ticks = None
    gains_path = None
    bare = False
    every = None
    usage = 'usage: python3 -m tipbot_fw.bench --ticks N [--gains FILE] [--bare] [--telemetry-every M]'
    while args:
        if args[0] == '--bare':
            bare = True
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
    if n_ticks is None:
        sys.stderr.write(usage + '\n')
        return 2
    if gains_path is None and os.path.isfile(REPO_GAINS):
        gains_path = REPO_GAINS
    gains = load_gains(gains_path) if gains_path else None
    sender, sink = local_sender(every) if every else (None, None)
    stats, _ = run_memory(n_ticks, gains, bare, sender)
    if stats.ticks != n_ticks + 1:
        sys.stderr.write('bench: the loop stopped after {} ticks\n'.format(stats.ticks))
        return 1
    sys.stdout.write('ticks {} (+1 start tick), gains {}{}\n'.format(
        n_ticks, gains_path or 'synthetic', ', bare (no heartbeat, plausibility or log file)' if bare else ''))
    if sender is not None:
        ts_s = gains.ts_s if gains else 0.005
        sys.stdout.write('telemetry: {} datagrams of {} bytes in {} ticks (one every {}: {:.0f} per second at '
                         '{:g} ms), {} not sent\n'.format(sender.sent, SIZE, n_ticks + 1, every,
                                                         1.0 / (every * ts_s), ts_s * 1e3, sender.errors))
        sender.close()
        sink.close()
    return 0


if __name__ == '__main__':
    sys.exit(main())
