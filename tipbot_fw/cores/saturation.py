"""From the unsaturated control law to what the motors actually get.

Saturating u at +-u_max_v, then duty = round(100 u / battery_v) clipped to +-100, equals clipping
round(100 u / battery_v) at +-dlim with dlim = min(100, round(100 u_max_v / battery_v)), because
rounding is monotonic (and symmetric: Python rounds half to even). The applied input, which the
detector is fed next tick, is duty * battery_v / 100.

The core folds 100 / battery_v and the motor polarities into its matrix (tipbot_fw.cores.core), so the
per-tick work here is rounding and clipping 4 numbers: scalar Python, several times cheaper on the
brick than np.clip.
"""


def battery_constants(u_max_v, battery_v):
    """-> (duty per volt, volts per duty, duty limit) at this battery voltage."""
    scale = 100.0 / battery_v
    return scale, battery_v / 100.0, min(100, round(u_max_v * scale))


def to_duties(q, dlim):
    """Unsaturated commands q (4, in duty units) -> (d0, d1, d2, d3, saturation bits).

    Duties are ints in [-dlim, dlim]; bit i (1, 2, 4, 8) is set when duty i was limited.
    Unrolled: a loop over the four, with its indexing and appends, costs twice as much.
    """
    q0, q1, q2, q3 = q
    bits = 0
    d0 = round(q0)
    if d0 > dlim:
        d0 = dlim
        bits = 1
    elif d0 < -dlim:
        d0 = -dlim
        bits = 1
    d1 = round(q1)
    if d1 > dlim:
        d1 = dlim
        bits |= 2
    elif d1 < -dlim:
        d1 = -dlim
        bits |= 2
    d2 = round(q2)
    if d2 > dlim:
        d2 = dlim
        bits |= 4
    elif d2 < -dlim:
        d2 = -dlim
        bits |= 4
    d3 = round(q3)
    if d3 > dlim:
        d3 = dlim
        bits |= 8
    elif d3 < -dlim:
        d3 = -dlim
        bits |= 8
    return d0, d1, d2, d3, bits
