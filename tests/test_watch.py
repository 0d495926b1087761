"""`python -m hostsim watch`: receives the firmware's telemetry while a command runs, records it
with the log's values, and draws the live view (headless here: into a PNG)."""
import csv
import os
import socket
import subprocess
import sys

import numpy as np
import pytest

import fw_support as S
from conftest import REPO
from hostsim.logs import watch
from tipbot_fw.record.replay import signals
from tipbot_fw.record.logfile import read_log


def col(header, name):
    return [c['name'] for c in header['columns']].index(name)

# A firmware run in another process: the real loop and session on in-memory devices whose
# readings move, on a virtual clock, sending telemetry to argv[1]; exit status 3 at the end.
RUN = '''
import os, sys
sys.path[:0] = [{tests!r}, os.path.dirname({tests!r})]
import fw_support as S
from tipbot_fw.io.clock import VirtualClock
from tipbot_fw.cues import OwnerCues
from tipbot_fw.io.devices import MemoryDevices
from tipbot_fw.session import run_session
from tipbot_fw.record.telemetry import TelemetrySender

dev = MemoryDevices()
dev.source = S.moving_readings()
sender = TelemetrySender(sys.argv[1], every=5)
code, header = run_session(dev, S.load(), S.fw_config(), VirtualClock(), log_path=sys.argv[2], duration_s=1.0,
                           say=lambda m: None, cues=OwnerCues(streams=()), telemetry=sender)
assert code == 0
sys.exit(3)
'''


def free_udp_port():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def read_record(path):
    with open(path) as f:
        return list(csv.DictReader(f))


@pytest.mark.slow
def test_watch_records_what_a_run_sends_and_draws_it(tmp_path):
    port = free_udp_port()
    script = tmp_path / 'run.py'
    script.write_text(RUN.format(tests=os.path.join(REPO, 'tests')))
    log, record, png = (str(tmp_path / n) for n in ('run.log', 'rec.csv', 'view.png'))
    p = subprocess.run([sys.executable, '-m', 'hostsim', 'watch', '--port', str(port), '--record', record,
                        '--snapshot', png, '--no-window', '--', sys.executable, str(script), '127.0.0.1:%d' % port, log],
                       cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, universal_newlines=True, timeout=120)
    assert p.returncode == 3, p.stdout            # the command's exit status
    assert 'watch: 40 datagrams in 1 run, 0 lost on the way, 0 not sent by the brick' in p.stdout, p.stdout
    header, rows = read_log(log)
    sig = signals(header, rows, S.load())
    got = read_record(record)
    assert [int(r['tick']) for r in got] == list(range(0, 200, 5))
    for r in got:
        for name, column in (('time_s', 'time_s'), ('battery_v', 'battery_v'), ('tick_s', 'tick_s'),
                             ('duty_r_pct', 'duty_r')):
            assert float(r[name]) == rows[int(r['tick']), col(header, column)], name
        for name, (key, j) in (('xt_th1_rad', ('x_hat', 2)), ('xt_d_l_m', ('x_hat', 1)), ('u_r_V', ('u', 0)),
                               ('w_r_V', ('w_hat', 0))):
            assert float(r[name]) == getattr(sig, key)[int(r['tick']), j], name
    assert os.path.getsize(png) > 20000
    # a recording shows again, from the file
    again = str(tmp_path / 'again.png')
    assert watch.main(['--from', record, '--snapshot', again, '--no-window', '--window', '0']) == 0
    assert os.path.getsize(again) > 20000


def test_runs_and_losses_are_told_apart():
    tel = watch.Telemetry()
    base = {f: 0.0 for f in watch.FIELDS}
    for seq, tick in [(0, 0), (1, 10), (4, 40), (0, 0), (1, 10)]:       # 2 lost, then a new run
        tel.add(dict(base, seq=seq, tick=tick, overruns=0, send_errors=0, time_s=tick * 0.005))
    assert (tel.received, tel.lost, tel.runs) == (5, 2, 2)
    assert tel.window(0) == (3, 5)          # the view shows the newest run only
    assert np.array_equal(tel.data['run'], [1, 1, 1, 2, 2])


def test_a_busy_port_or_a_bad_recording_gets_one_line(tmp_path, capsys):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(('127.0.0.1', 0))
        port = s.getsockname()[1]
        assert watch.main(['--port', str(port), '--bind', '127.0.0.1', '--duration', '0.1', '--no-window']) == 2
    assert 'watch: error: cannot listen on UDP 127.0.0.1:%d' % port in capsys.readouterr().err
    bad = tmp_path / 'bad.csv'
    bad.write_text('a,b\n1,2\n')
    assert watch.main(['--from', str(bad), '--no-window']) == 2
    assert 'not a recording of hostsim watch' in capsys.readouterr().err


def test_the_readme_screenshot_is_what_watch_draws_of_its_recording(tmp_path):
    # docs/watch.png: a loopback run (fake robot, 1 V on the wheels from 5 to 10 s, a push at
    # 12 s) recorded by watch and drawn from the recording, as docs/deploy.md says
    import matplotlib.image
    again = str(tmp_path / 'watch.png')
    recording = os.path.join(REPO, 'docs', 'watch-recording.csv')
    assert watch.main(['--from', recording, '--window', '15', '--snapshot', again, '--no-window']) == 0
    a = matplotlib.image.imread(os.path.join(REPO, 'docs', 'watch.png'))
    b = matplotlib.image.imread(again)
    assert a.shape == b.shape and np.abs(a - b).mean() < 0.002


@pytest.mark.slow
def test_the_live_window_follows_the_run(tmp_path, monkeypatch):
    # the window's code path (a redraw every 0.1 s while the command runs, then the window
    # stays until closed) with Agg standing in for a display
    import matplotlib
    matplotlib.use('Agg', force=True)
    import matplotlib.pyplot as plt
    monkeypatch.setattr(watch, 'pyplot', lambda window: (plt, True))
    updates = []
    update = watch.View.update
    monkeypatch.setattr(watch.View, 'update', lambda self, tel, note='': updates.append(tel.received) or
                        update(self, tel, note))
    port = free_udp_port()
    script = tmp_path / 'run.py'
    script.write_text(RUN.format(tests=os.path.join(REPO, 'tests')))
    status, tel = watch.watch(port, snapshot=str(tmp_path / 'v.png'), command=[
        sys.executable, str(script), '127.0.0.1:%d' % port, str(tmp_path / 'run.log')])
    assert status == 3 and tel.received == 40 and tel.runs == 1
    assert len(updates) > 5 and updates[-1] == 40
    assert os.path.getsize(str(tmp_path / 'v.png')) > 20000
    plt.close('all')


def test_without_a_display_watch_says_what_it_keeps(tmp_path, monkeypatch, capsys):
    """No display: nothing is kept unless asked, and the message says so; a recording asked for
    lands where it was asked, its folder made."""
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    watch.watch(0, duration_s=0.2, bind="127.0.0.1")
    out = capsys.readouterr().out
    assert "watch: no display: nothing is drawn or kept (give RECORD=file.csv or SNAPSHOT=file.png)" in out
    record = tmp_path / "new" / "run.csv"
    watch.watch(0, record=str(record), duration_s=0.2, bind="127.0.0.1")
    assert "watch: no display: keeping the datagrams to %s" % record in capsys.readouterr().out
    assert record.read_text().startswith("run,seq,tick,")
