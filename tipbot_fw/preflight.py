"""The pre-flight check: do the owner's fall and swing tests describe the robot these gains were
made for? (issue 24)

    python3 -m tipbot_fw check --gains gains.json --fall-log LOG [--swing-log LOG]...

The gains file's ``preflight`` block (made by ``make gains``: hostsim.model.preflight) holds the
fall pole and the joints' levers of the gains' robot, each with the interval over which the
design still holds the robot. The check fits the logs (tipbot_fw.bodyfit, with the gains'
parameters for the motors and the wheels) and passes a measurement only when it lies inside its
interval by at least its standard deviation (the fit's own standard error and what the fit's model
leaves out, tipbot_fw.bodyfit.MODEL_ERROR, as the host's fit weighs it): a value outside
(``OUTSIDE``) is a robot the gains were not made for, one inside but nearer the edge than that
(``UNSURE``) one they may hold only by luck, or a measurement too loose to tell; either refuses,
saying which measurement and by how much. (Passing a robot the gains do not hold costs a fall on
its first balance; refusing one at the edge, a measurement or a description again. A robot whose
link 3 is twice as heavy as entered lies only 2 % beyond the committed gains' interval: once the
joint-3 swing read it to -1 %, a check that gave the doubt to the robot, as this one did until
2026-12-05, passed it.) A fall log is required; swing logs
are checked when given (a heavier link 3 hardly moves the fall pole: the swing of joint 3 is what
sees it).

Python 3.5 and numpy 1.12.
"""
import math

from tipbot_fw import fields

QUANTITIES = ('fall_pole_1_s', 'lever2_kg_m', 'lever3_kg_m')


class PreflightError(ValueError):
    """A log or gains file the check cannot use (the message names it)."""


def check_block(f, block):
    """Validate a gains document's ``preflight`` block with the gains' Fields ``f``; -> the block
    or None when absent (gains made before issue 24)."""
    if block is None:
        return None
    f.check('preflight', block, fields.obj)
    f.check('preflight.intervals', block.get('intervals'), fields.obj)
    for name in QUANTITIES:
        lo, hi = f.check('preflight.intervals.' + name, block['intervals'].get(name), fields.numbers(2))
        if not 0 < lo <= hi:
            f.fail('preflight.intervals.' + name, 'must be an interval 0 < lo <= hi, got {!r}'.format([lo, hi]))
    f.check('preflight.levers_kg_m', block.get('levers_kg_m'), fields.numbers(3))
    for key in ('fall_pole_1_s', 'wheel_term_kg_m2', 'lever_axle_kg_m'):
        f.number('preflight.' + key, block.get(key), lo=0.0)
    return block


def _read(path, kind):
    from tipbot_fw.record import logfile
    try:
        header, rows = logfile.read_log(path)
    except (OSError, ValueError) as e:      # LogFormatError is a ValueError
        raise PreflightError('{}: cannot read: {}'.format(path, e))
    if header.get('kind') != kind:
        raise PreflightError('{}: not a {} log (kind {!r})'.format(path, kind, header.get('kind')))
    if header.get('stop_reason') != 'completed':
        raise PreflightError('{}: the {} test did not complete ({}): do it again'.format(
            path, kind, header.get('stop_message')))
    return header, rows


def measure(gains, fall_log, swing_logs=()):
    """Fit the logs -> {quantity: (value, relative standard deviation (the fit's and its model's), log)}.
    PreflightError."""
    from tipbot_fw import bodyfit     # here: a balance run loads the gains (check_block), not the fits
    p = gains.parameters
    block = gains.preflight
    out = {}
    header, rows = _read(fall_log, 'fall')
    try:
        fit = bodyfit.fit_fall(bodyfit.signals(header, rows), p['rw_m'], p['g_m_s2'],
                               block['wheel_term_kg_m2'] / block['lever_axle_kg_m'])
    except bodyfit.FitError as e:
        raise PreflightError('{}: {}'.format(fall_log, e))
    # the pole is the square root of g over the ratio: half the ratio's relative error
    out['fall_pole_1_s'] = (fit['pole_1_s'], math.hypot(fit['pole_rel_se'], 0.5 * bodyfit.MODEL_ERROR['fall_ratio']),
                            fall_log)
    fits = {}
    for path in swing_logs:
        header, rows = _read(path, 'swing')
        fits[header['joint']] = (header, rows, path)
    for joint in (3, 2):         # joint 3 first: joint 2's fit takes link 3's lever
        if joint not in fits:
            continue
        header, rows, path = fits[joint]
        k_v, c, _ = bodyfit.motor_constants(p, joint)
        lever3 = out['lever3_kg_m'][0] if 'lever3_kg_m' in out else block['levers_kg_m'][2]
        try:
            fit = bodyfit.fit_swing(bodyfit.signals(header, rows), joint, k_v, c, p['g_m_s2'],
                                    lever3=lever3 if joint == 2 else None)
        except bodyfit.FitError as e:
            raise PreflightError('{}: {}'.format(path, e))
        out['lever{}_kg_m'.format(joint)] = (fit['lever_kg_m'], math.hypot(fit['lever_se'] / fit['lever_kg_m'],
                                                                          bodyfit.MODEL_ERROR['lever%d' % joint]), path)
    return out


def verdict(gains, measured):
    """-> (ok, lines): each measurement against the gains' interval."""
    block = gains.preflight
    model = {'fall_pole_1_s': block['fall_pole_1_s'], 'lever2_kg_m': block['levers_kg_m'][1],
             'lever3_kg_m': block['levers_kg_m'][2]}
    lines, ok = [], True
    for name in QUANTITIES:
        if name not in measured:
            lines.append('{:14s} not measured'.format(name))
            continue
        value, rel_se, path = measured[name]
        lo, hi = block['intervals'][name]
        margin = rel_se * value
        inside = lo <= value - margin and value + margin <= hi
        ok = ok and inside
        state = 'ok' if inside else '{} ({})'.format('OUTSIDE' if not lo <= value <= hi else 'UNSURE', path)
        lines.append('{:14s} measured {:.4g} (+-{:.1f} %), the gains\' robot {:.4g} ({:+.0f} %), they hold {:.4g}..{:.4g}: {}'
                     .format(name, value, 100 * rel_se, model[name], 100 * (value / model[name] - 1), lo, hi,
                             state))
    return ok, lines


def run_check(gains, fall_log, swing_logs=(), say=print):
    """The check -> (ok, why): says each line, then the verdict."""
    if gains.preflight is None:
        why = ('{}: the gains carry no preflight block (made before the pre-flight check existed): '
               'run make gains again'.format(gains.path))
        say('pre-flight: REFUSED: ' + why)
        return False, why
    try:
        measured = measure(gains, fall_log, swing_logs)
    except PreflightError as e:
        say('pre-flight: REFUSED: {}'.format(e))
        return False, str(e)
    ok, lines = verdict(gains, measured)
    for line in lines:
        say('pre-flight: ' + line)
    if ok:
        say('pre-flight: ok: the robot is the one these gains were made for, as far as the tests see')
        return True, ''
    bad = [line.split()[0] for line in lines if 'OUTSIDE' in line]
    unsure = [line.split()[0] for line in lines if 'UNSURE' in line]
    why = []
    if bad:
        why.append('the robot is not the one {} was made for: {} outside what the gains hold; describe the robot '
                   'again (python -m hostsim describe / fit-robot) and make gains for it'.format(
                       gains.path, ', '.join(bad)))
    if unsure:
        why.append('{} within its standard deviation of the edge of what {} holds: do that test again '
                   '(a still hold, a fresh battery), or fit the robot and make gains for it'.format(
                       ', '.join(unsure), gains.path))
    why = '; '.join(why)
    say('pre-flight: REFUSED: ' + why)
    return False, why
