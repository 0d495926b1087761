"""Live telemetry (tipbot_fw.record.telemetry): datagrams every few ticks in the loop's slack that decode
to the log's own values, and a network that never disturbs the loop."""
import socket
import struct

import numpy as np
import pytest

import fw_support as S
from tipbot_fw import bench, cli
from tipbot_fw.record import telemetry
from tipbot_fw.io.clock import VirtualClock
from tipbot_fw.cores.core import make_core
from tipbot_fw.cues import OwnerCues
from tipbot_fw.io.devices import MemoryDevices
from tipbot_fw.record.logfile import read_log
from tipbot_fw.record.replay import signals
from tipbot_fw.session import run_session
from tipbot_fw.record.telemetry import TelemetryError, TelemetrySender, decode
from tipbot_fw import vocabulary
from tipbot_fw.cores.detector_rows import DetectorRows


@pytest.fixture
def sink():
    """A UDP socket on 127.0.0.1 and its HOST:PORT."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(('127.0.0.1', 0))
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
    s.settimeout(0.2)
    yield s, '127.0.0.1:%d' % s.getsockname()[1]
    s.close()


def received(sock):
    out = []
    while True:
        try:
            out.append(sock.recv(4096))
        except socket.timeout:
            return out


def moving_run(tmp_path, sender, polarity=1, duration_s=0.6, estimator='kalman'):
    """A session whose readings move (so every value differs from tick to tick); -> (header, rows)."""
    dev = MemoryDevices()
    dev.source = S.moving_readings(polarity)
    path = str(tmp_path / 'run.log')
    code, header = run_session(dev, S.load(), S.fw_config(polarity={'right_wheel': polarity}, estimator=estimator),
                               VirtualClock(), log_path=path, duration_s=duration_s, say=lambda m: None,
                               cues=OwnerCues(streams=()), telemetry=sender)
    assert code == 0
    return read_log(path)


def logged_values(header, rows, gains):
    """{decoded name: the log's values}: the file's own columns and the replay's signals()."""
    names = [c['name'] for c in header['columns']]
    out = {n: rows[:, names.index(n)] for n in ('time_s', 'tick_s', 'battery_v', 'flags', 'duty_r', 'duty_l',
                                                'duty_2', 'duty_3')}
    sig = signals(header, rows, gains)
    for i, s in enumerate(vocabulary.STATE_NAMES):
        out['xt_' + s] = sig.x_hat[:, i]
    for name, j in zip(('r', 'l', 'th2', 'th3'), (0, 1, 3, 4)):
        out['w_' + name], out['u_' + name] = sig.w_hat[:, j], sig.u[:, j]
    assert sorted(out) == sorted(telemetry.DECODED)
    return out


@pytest.mark.parametrize('estimator', ['kalman', 'detector'])
@pytest.mark.parametrize('polarity', [1, -1])
def test_datagrams_carry_every_nth_tick_with_the_values_of_the_log(tmp_path, sink, polarity, estimator):
    sock, target = sink
    sender = TelemetrySender(target, every=7)
    header, rows = moving_run(tmp_path, sender, polarity, estimator=estimator)
    got = [decode(d) for d in received(sock)]
    assert header['telemetry'] == {'target': target, 'every_ticks': 7, 'sent': len(got), 'errors': 0,
                                   'first_error': None}
    # the first tick's row, then every 7th: the loop's last tick (120) asks nothing of the slack
    assert [g['tick'] for g in got] == list(range(0, len(rows) - 1, 7))
    assert [g['seq'] for g in got] == list(range(len(got)))
    logged = logged_values(header, rows, S.load())
    for g in got:
        for name in telemetry.DECODED:
            assert g[name] == logged[name][g['tick']], (g['tick'], name)      # the same bits
        assert g['overruns'] == 0 and g['send_errors'] == 0
    for name in ('xt_d_r', 'xt_th1', 'w_r', 'u_r'):       # not vacuous: they all moved
        assert np.ptp([g[name] for g in got]) > 0, name


def test_nobody_listening_is_counted_and_never_stops_the_loop(tmp_path, sink):
    sock, target = sink
    sock.close()    # the port is closed: the kernel answers "connection refused"
    sender = TelemetrySender(target, every=1)
    header, rows = moving_run(tmp_path, sender, duration_s=0.2)
    t = header['telemetry']
    assert len(rows) == 40 and t['errors'] > 0 and t['sent'] + t['errors'] == 39
    assert 'refused' in t['first_error'].lower()


def test_a_socket_that_fails_outright_is_counted_too(tmp_path, sink):
    sender = TelemetrySender(sink[1], every=2)
    sender.sock.close()          # every send now fails (EBADF)
    header, rows = moving_run(tmp_path, sender, duration_s=0.2)
    assert header['telemetry']['sent'] == 0 and header['telemetry']['errors'] == 20 and len(rows) == 40


def test_the_encoder_follows_the_row_by_name():
    # a row with the same columns in another order and with others between them
    fields = telemetry.ROW_FIELDS['detector']
    names = list(DetectorRows.mem_names)[::-1] + ['extra']
    row = np.arange(len(names), dtype='<f8')
    unpack, pack = telemetry.row_copier(fields, names)
    body = telemetry.Layout(0).body
    out = bytearray(body.size)
    pack(out, 0, *unpack(row.tobytes(), 0))
    assert list(body.unpack(bytes(out))) == [float(names.index(n)) for n in fields]
    # the rows as the cores lay them out: four runs of columns (detector), three (Kalman), two C calls
    kalman_rows = make_core(S.load(), S.fw_config()).rows
    kalman_fields = telemetry.Layout.of_rows(kalman_rows).fields
    assert 'xi_gyro_bias' in kalman_fields and kalman_fields[-2:] == ('rel_r', 'rel_l')
    assert telemetry.row_copier(fields, DetectorRows.mem_names)[1].__self__.format == '<16s8s40s112s'
    assert telemetry.row_copier(kalman_fields, kalman_rows.mem_names)[1].__self__.format == '<32s136s16s'
    with pytest.raises(TelemetryError, match="the log row has no column xt_th1"):
        telemetry.row_copier(fields, [n for n in DetectorRows.mem_names if n != 'xt_th1'])


def test_foreign_datagrams_are_refused():
    with pytest.raises(TelemetryError, match='not a tipbot telemetry datagram'):
        decode(b'hello')
    good = bytearray(telemetry.Layout(0).size)
    telemetry.HEADER.pack_into(good, 0, telemetry.MAGIC, 3, 0, 0, 0, 0, 0, 0, 0.0)
    with pytest.raises(TelemetryError, match='telemetry version 3'):
        decode(bytes(good))
    telemetry.HEADER.pack_into(good, 0, telemetry.MAGIC, 2, 0x40, 0, 0, 0, 0, 0, 0.0)
    with pytest.raises(TelemetryError, match='layout 0x40 is not one this reader knows'):
        decode(bytes(good))
    with pytest.raises(TelemetryError, match='its layout has 208'):
        decode(bytes(good[:-8]).replace(b'\x40', b'\x00', 1))


@pytest.mark.parametrize('target, why', [('nohost', 'must be HOST:PORT'), ('h:0', 'must be HOST:PORT'),
                                         ('h:99999', 'must be HOST:PORT'), (':5005', 'must be HOST:PORT'),
                                         ('no.such.host.invalid:5005', '--telemetry no.such.host.invalid:5005: ')])
def test_a_bad_target_is_refused_before_any_device_is_touched(tmp_path, capsys, target, why):
    code = cli.main(['run', '--gains', S.write_json(tmp_path / 'g.json', S.gains_doc()), '--telemetry', target,
                     '--sysfs-root', str(tmp_path / 'no-such-tree')])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith('tipbot: refused to start: ') and why in err
    assert len(err.strip().splitlines()) == 1


def test_ipv6_targets_parse():
    assert telemetry.parse_target('[::1]:5005') == ('::1', 5005)
    assert telemetry.parse_target('::1:5005') == ('::1', 5005)    # as `make watch` builds it from SSH_CLIENT


def test_the_bench_measures_the_loop_with_telemetry(capsys):
    assert bench.main(['--ticks', '200', '--telemetry-every', '10']) == 0
    out = capsys.readouterr().out
    assert 'telemetry: 20 datagrams of 384 bytes in 201 ticks (one every 10: 20 per second at 5 ms), 0 not sent' in out


def test_the_datagram_layout_is_what_docs_telemetry_says():
    assert telemetry.HEADER.size == struct.calcsize('<4sHBBIIIId') == 32
    assert telemetry.Layout(0).size == 32 + 22 * 8                                   # the detector's
    kal = telemetry.Layout(telemetry.KALMAN | 3)                                      # the Kalman filter's, w_r, w_l
    assert kal.size == 32 + (4 + 4 + 13 + 2) * 8 + (13 + 2) * 8 == 336
    assert kal.states[10:] == ['w_r', 'w_l', 'gyro_bias']


def test_a_driven_runs_datagrams_carry_its_reference_as_the_log_has_it(tmp_path, sink):
    from conftest import PHYSICAL_GAINS
    from tipbot_fw.gains import load_gains
    sock, target = sink
    sender = TelemetrySender(target, every=5)
    dev = MemoryDevices()
    dev.source = S.moving_readings(1)
    path = str(tmp_path / 'run.log')
    code, header = run_session(dev, load_gains(PHYSICAL_GAINS), S.fw_config(), VirtualClock(), log_path=path,
                               duration_s=0.6, say=lambda m: None, cues=OwnerCues(streams=()), telemetry=sender,
                               course=[(0.1, 0.2, 1.0)])
    header, rows = read_log(path)
    got = [decode(d) for d in received(sock)]
    assert got and all(sorted(g) == sorted(telemetry.DECODED_DRIVING + ['seq', 'tick', 'overruns', 'send_errors']) for g in got)
    names = [c['name'] for c in header['columns']]
    for g in got:
        for name in telemetry.REFERENCE_NAMES:
            assert g[name] == rows[g['tick'], names.index(name)], (g['tick'], name)     # the same bits
    assert max(g['ref_v_r'] for g in got) > 0.05
    assert telemetry.Layout(telemetry.KALMAN | telemetry.REFERENCE | 3).size == 336 + 96
