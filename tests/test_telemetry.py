"""Live telemetry (tipbot_fw.telemetry): datagrams every few ticks in the loop's slack that decode
to the log's own values, and a network that never disturbs the loop."""
import socket
import struct

import numpy as np
import pytest

import fw_support as S
from tipbot_fw import bench, cli, logfile, telemetry
from tipbot_fw.clock import VirtualClock
from tipbot_fw.cues import OwnerCues
from tipbot_fw.devices import MemoryDevices
from tipbot_fw.logfile import col, read_log
from tipbot_fw.session import run_session
from tipbot_fw.telemetry import TelemetryError, TelemetrySender, decode


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


def moving_run(tmp_path, sender, polarity=1, duration_s=0.6):
    """A session whose readings move (so every value differs from tick to tick); -> (header, rows)."""
    dev = MemoryDevices()
    dev.source = S.moving_readings(polarity)
    path = str(tmp_path / 'run.log')
    code, header = run_session(dev, S.load(), S.fw_config(polarity={'right_wheel': polarity}), VirtualClock(),
                               log_path=path, duration_s=duration_s, say=lambda m: None, cues=OwnerCues(streams=()),
                               telemetry=sender)
    assert code == 0
    return read_log(path)


@pytest.mark.parametrize('polarity', [1, -1])
def test_datagrams_carry_every_nth_tick_with_the_values_of_the_log(tmp_path, sink, polarity):
    sock, target = sink
    sender = TelemetrySender(target, every=7)
    header, rows = moving_run(tmp_path, sender, polarity)
    got = [decode(d) for d in received(sock)]
    assert header['telemetry'] == {'target': target, 'every_ticks': 7, 'sent': len(got), 'errors': 0,
                                   'first_error': None}
    # the first tick's row, then every 7th: the loop's last tick (120) asks nothing of the slack
    assert [g['tick'] for g in got] == list(range(0, len(rows) - 1, 7))
    assert [g['seq'] for g in got] == list(range(len(got)))
    for g in got:
        row = rows[g['tick']]
        for name in ('time_s', 'tick_s', 'battery_v', 'flags', 'y_d_r', 'y_d_l', 'y_th1', 'y_th2', 'y_th3',
                     'w_r', 'w_l', 'w_th2', 'w_th3', 'u_r', 'u_l', 'u_th2', 'u_th3', 'duty_r', 'duty_3'):
            assert g[name] == row[col(name)], (g['tick'], name)      # the same bits
        assert g['overruns'] == 0 and g['send_errors'] == 0
    assert np.ptp([g['y_d_r'] for g in got]) > 0 and np.ptp([g['u_r'] for g in got]) > 0


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
    names = list(logfile.MEM_NAMES)[::-1] + ['extra']
    row = np.arange(len(names), dtype='<f8')
    unpack, pack = telemetry.row_copier(telemetry.ROW_FIELDS, names)
    out = bytearray(telemetry.BODY.size)
    pack(out, 0, *unpack(row.tobytes(), 0))
    assert list(telemetry.BODY.unpack(bytes(out))) == [float(names.index(n)) for n in telemetry.ROW_FIELDS]
    # today's row: three runs of columns, two C calls
    assert len(telemetry.row_copier(telemetry.ROW_FIELDS)[1].__self__.format) < 20
    with pytest.raises(TelemetryError, match="the log row has no column y_th1"):
        telemetry.row_copier(telemetry.ROW_FIELDS, [n for n in logfile.MEM_NAMES if n != 'y_th1'])


def test_foreign_datagrams_are_refused():
    with pytest.raises(TelemetryError, match='not a tipbot telemetry datagram'):
        decode(b'hello')
    good = bytearray(telemetry.SIZE)
    telemetry.HEADER.pack_into(good, 0, telemetry.MAGIC, 2, 0, 0, 0, 0, 0, 0.0)
    with pytest.raises(TelemetryError, match='telemetry version 2'):
        decode(bytes(good))


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
    assert 'telemetry: 20 datagrams of %d bytes in 201 ticks (one every 10: 20 per second at 5 ms), 0 not sent' \
        % telemetry.SIZE in out


def test_the_datagram_layout_is_what_docs_telemetry_says():
    assert (telemetry.HEADER.size, telemetry.SIZE) == (32, 176)
    assert struct.calcsize('<4sHHIIIId') == 32
