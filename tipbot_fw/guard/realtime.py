"""SCHED_FIFO for the control loop and its supervisor (stdlib only: the supervisor imports it).

An unprivileged process may take SCHED_FIFO up to its RLIMIT_RTPRIO. ``./install.sh --rtprio``
grants the robot user that limit (a pam_limits file: ssh and login sessions), and
``tipbot.service`` grants it with ``LimitRTPRIO=``; a session whose soft limit is below its hard
one (``ulimit -Sr``) is raised to the hard limit here first, as any process may do itself.
"""
import errno
import os

try:
    import resource
except ImportError:     # not a POSIX system: no rtprio limit to raise
    resource = None


def _raise_soft_rtprio(priority):
    """Soft RLIMIT_RTPRIO up to min(priority, hard) if it is lower. -> the (soft, hard) limits."""
    if resource is None or not hasattr(resource, 'RLIMIT_RTPRIO'):
        return None
    soft, hard = resource.getrlimit(resource.RLIMIT_RTPRIO)
    unlimited = resource.RLIM_INFINITY
    want = priority if hard == unlimited else min(priority, hard)
    if soft != unlimited and soft < want:
        try:
            resource.setrlimit(resource.RLIMIT_RTPRIO, (want, hard))
            soft = want
        except (ValueError, OSError):
            pass
    return soft, hard


def ask_fifo(priority):
    """Switch this process to SCHED_FIFO at ``priority`` (<= 0: don't). -> (info, restore):
    info = {'requested_priority', 'granted', 'error', 'errno', 'rtprio_limit'} for the log and
    the start line (refused(info): the kernel said EPERM); restore() puts back the scheduling it had."""
    info = {'requested_priority': priority, 'granted': False, 'error': None, 'errno': None, 'rtprio_limit': None}
    if priority <= 0 or not hasattr(os, 'sched_setscheduler'):
        info['error'] = 'not requested' if priority <= 0 else 'not supported on this platform'
        return info, lambda: None
    limits = _raise_soft_rtprio(priority)
    if limits is not None:
        info['rtprio_limit'] = [-1 if v == resource.RLIM_INFINITY else int(v) for v in limits]
    try:
        old_policy = os.sched_getscheduler(0)
        old_param = os.sched_getparam(0)
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except OSError as e:
        info['error'], info['errno'] = str(e), e.errno
        return info, lambda: None
    info['granted'] = True

    def restore():
        try:
            os.sched_setscheduler(0, old_policy, old_param)
        except OSError:
            pass
    return info, restore


def refused(info):
    """Was SCHED_FIFO asked for and not permitted (no rtprio limit granted: install.sh --rtprio)?"""
    return info['errno'] == errno.EPERM
