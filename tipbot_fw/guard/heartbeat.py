"""The page the controller and its supervisor share (tipbot_fw.supervisor). Standard library only.

One 4 KiB page of a file the supervisor creates, unlinks and passes to the controller as a file
descriptor (on tmpfs, /dev/shm, when there is one: a heartbeat must never reach the SD card).
Both map it; each word is an aligned native 32-bit unsigned integer, so a store or a load is one
machine instruction and never torn:

  BEAT     the controller's tick counter: the control loop stores its tick index every tick
           (one subscript store, no system call: tipbot_fw.loop), and the calibration every sample
  STATE    IDLE: not watched (start-up, between the calibration and the first tick, after the
           motors are stopped); ARMED: the supervisor stops the motors when BEAT stands still
           longer than its timeout
  STOPPED  set by the supervisor when it stopped the motors because BEAT stood still: then the
           controller's SIGTERM handler reports a stall (stop reason ``watchdog``), not a SIGTERM
  MISSED_US  how long BEAT had stood still then, in microseconds
  REQUEST  a termination signal the supervisor received (and passed on): the controller checks it
           when its signal handlers are installed, so a signal that reached it before then (when
           it was still ignored) is not lost
  POLLS    the supervisor's poll counter (for tests and diagnostics)
  RAIL     the duty the controller's saturation limits each motor to (u_max_v at the battery's
           last reading): a frozen controller whose held duties sit there was already fighting
           a fall, and is stopped without waiting (tipbot_fw.supervisor); written outside the
           ticks, whenever the battery reading changes

The controller finds the page through the environment variable TIPBOT_SUPERVISOR
("<page fd>:<pipe fd>:<supervisor pid>"); the pipe's write end is only held open, so that the
supervisor sees the controller's end (any end: SIGKILL, a crash, the OOM killer) at once, as an
end of file.
"""
import mmap
import os

ENV = 'TIPBOT_SUPERVISOR'
PAGE_BYTES = 4096
BEAT, STATE, STOPPED, MISSED_US, REQUEST, POLLS, RAIL = range(7)
IDLE, ARMED = 0, 1


def map_page(fd):
    """-> (mmap, memoryview of native unsigned 32-bit words) of the shared page in fd."""
    page = mmap.mmap(fd, PAGE_BYTES)
    return page, memoryview(page).cast('I')


def create_page():
    """Supervisor side: -> (fd, mmap, words) of a fresh zeroed page in an unlinked file."""
    # not tempfile: it imports random, shutil and the compressors, a megabyte of the supervisor's
    # (and its guard's) memory on the brick
    where = '/dev/shm' if os.path.isdir('/dev/shm') and os.access('/dev/shm', os.W_OK) else \
        os.environ.get('TMPDIR') or '/tmp'
    for n in range(1000):
        path = os.path.join(where, 'tipbot-heartbeat-{}-{}'.format(os.getpid(), n))
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o600)
        except FileExistsError:
            continue
        os.unlink(path)
        break
    else:
        raise OSError(17, 'no free heartbeat page name in {}'.format(where))
    os.ftruncate(fd, PAGE_BYTES)
    page, words = map_page(fd)
    return fd, page, words


class Heartbeat(object):
    """Controller side. ``words`` is the shared page (None: not supervised, every method a no-op);
    ``words[BEAT] = k`` is what the tick does (tipbot_fw.loop takes ``words`` as a local)."""

    def __init__(self, words=None, supervisor_pid=None, page=None):
        self.words = words
        self.supervisor_pid = supervisor_pid
        self._page = page

    @property
    def supervised(self):
        return self.words is not None

    def arm(self):
        if self.words is not None:
            self.words[BEAT] = 0
            self.words[STATE] = ARMED

    def disarm(self):
        if self.words is not None:
            self.words[STATE] = IDLE

    def beat(self, k):
        if self.words is not None:
            self.words[BEAT] = k & 0xffffffff

    def publish_rail(self, duty_limit):
        if self.words is not None:
            self.words[RAIL] = int(duty_limit)

    def stopped_by_supervisor(self):
        """-> the time BEAT had stood still (s) if the supervisor stopped the motors, else None."""
        if self.words is None or not self.words[STOPPED]:
            return None
        return self.words[MISSED_US] * 1e-6

    def requested_signal(self):
        """A termination signal the supervisor received before the controller could handle it, or 0."""
        return 0 if self.words is None else self.words[REQUEST]

    def supervisor_alive(self):
        """False once the supervisor is gone (our parent changed): a backup of the parent-death
        signal (attach), checked outside the ticks."""
        return self.supervisor_pid is None or os.getppid() == self.supervisor_pid


NOT_SUPERVISED = Heartbeat()


def set_parent_death_signal(signum):
    """prctl(PR_SET_PDEATHSIG, signum): the kernel sends signum when our parent (the supervisor)
    ends. -> None, or why it could not be set."""
    try:
        import ctypes
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(1, signum, 0, 0, 0) != 0:     # PR_SET_PDEATHSIG = 1
            return os.strerror(ctypes.get_errno())
    except (OSError, AttributeError, ImportError) as e:
        return str(e)
    return None


def attach(environ=None, death_signal=None):
    """The controller's Heartbeat from TIPBOT_SUPERVISOR (NOT_SUPERVISED without it), with the
    parent-death signal set. -> (Heartbeat, problem or None). A supervisor that is already gone
    (our parent is not its pid) is reported as a problem: the caller must not drive motors."""
    import signal
    environ = os.environ if environ is None else environ
    spec = environ.get(ENV)
    if not spec:
        return NOT_SUPERVISED, None
    try:
        page_fd, _, pid = (int(v) for v in spec.split(':'))
        page, words = map_page(page_fd)
    except (ValueError, OSError) as e:
        return NOT_SUPERVISED, '{}={!r} is not usable: {}'.format(ENV, spec, e)
    # If prctl is not available, the parent check outside the ticks still covers the death.
    set_parent_death_signal(signal.SIGTERM if death_signal is None else death_signal)
    hb = Heartbeat(words, pid, page)
    if not hb.supervisor_alive():
        return hb, 'the supervisor (pid {}) is gone'.format(pid)
    return hb, None
