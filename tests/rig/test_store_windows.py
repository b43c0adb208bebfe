"""The session store under Windows' file semantics (issue 24, 2 and 5): a file another
process holds open cannot be replaced or renamed (sharing violation), descriptors are
text-mode without ``O_BINARY``, ``os.statvfs`` does not exist. On Linux through
:mod:`nmsid.testing.windows_emulation`; on the Windows interpreter against Windows itself
(the emulation installs nothing there)."""

import os
import subprocess
import sys

import h5py
import numpy as np
import pytest

import nmsid.protocols.session_publish as pub
from nmsid.protocols import os_platform
from nmsid.protocols.session_file import (
    Calibration,
    Trial,
    read_session,
    validate_session,
)
from nmsid.protocols.session_publish import FileHeldError, publish_image
from nmsid.rig.journal import load_trial_npz
from nmsid.rig.session_log import SessionLog, journal_dir, recover
from nmsid.testing.windows_emulation import emulate_windows

FAST = (0.01, 0.02, 0.04)  # the retry's backoff, shortened for the tests


def _trial(i, n=500):
    rng = np.random.default_rng(7 + i)
    lsb = 20.0 / 65536
    # rE holds many 0x0A bytes: a text-mode descriptor would corrupt them
    rE = np.frombuffer(np.full(8 * n, 0x0A, np.uint8).tobytes(), np.float64) * 0 + \
        rng.random(n)
    return Trial(sE=0.3 + 0.05 * i, repeat=1, fs_Hz=2000.0, rE=rE,
                 I_ext_mA=rng.random(n), I_flex_mA=rng.random(n), force_N=rng.normal(size=n),
                 started_utc="2026-11-22T01:00:00Z", extra_attrs={"schedule_index": i},
                 wrench=np.rint(rng.normal(scale=300, size=(n, 6))) * lsb,
                 sync=(rng.random(n) > 0.5) * 5.0)


def _new_log(path):
    log = SessionLog.create(path, participant="P01", config_json="{}", seed=3,
                            backend="test", schedule_json="[]")
    log.write_calibration(Calibration(1, 9, 1.5, 10))
    return log


class Reader:
    """A second process holding the file open with h5py (HDFView, a notebook...)."""

    def __init__(self, path):
        code = ("import sys, h5py; f = h5py.File(sys.argv[1], 'r'); "
                "print(len(f['trials']), flush=True); sys.stdin.readline(); f.close()")
        self.proc = subprocess.Popen([sys.executable, "-c", code, str(path)],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        self.n_trials_seen = int(self.proc.stdout.readline())

    def close(self):
        self.proc.stdin.write("\n")
        self.proc.stdin.flush()
        assert self.proc.wait(timeout=30) == 0


def _plain_h5py_equals(path, trials):
    """Read back with plain h5py (no nmsid code): every sample bit for bit."""
    with h5py.File(path, "r") as f:
        names = sorted(f["trials"])
        assert len(names) == len(trials)
        for name, t in zip(names, trials, strict=True):
            g = f["trials"][name]
            for key in ("rE", "I_ext_mA", "I_flex_mA", "force_N"):
                assert g[key][()].tobytes() == np.asarray(getattr(t, key)).tobytes(), key
            w = g["wrench"]
            values = (w[()] * w.attrs["scale"] + w.attrs["offset"] if "scale" in w.attrs
                      else w[()].astype(np.float64))
            assert np.array_equal(values, t.wrench)


def test_a_reader_holding_the_live_file_across_trial_ends_costs_nothing(tmp_path):
    path = tmp_path / "W.h5"
    trials = [_trial(i) for i in range(5)]
    with emulate_windows():
        assert os_platform.is_windows()
        log = _new_log(path)
        reader = Reader(path)  # holds the live file from the first trial on
        assert reader.n_trials_seen == 0
        for t in trials:
            log.end_trial(t)  # never blocked, never fails
        reader.close()
        assert log.finish() is True
        assert not journal_dir(path).exists()
    _plain_h5py_equals(path, trials)
    assert validate_session(path) == []


def test_a_reader_holding_the_file_through_the_end_keeps_the_journal_and_names_the_file(
        tmp_path, monkeypatch, caplog):
    monkeypatch.setattr(pub, "RETRY_DELAYS_S", FAST)
    path = tmp_path / "W.h5"
    trials = [_trial(i) for i in range(3)]
    with emulate_windows():
        log = _new_log(path)
        reader = Reader(path)
        for t in trials:
            log.end_trial(t)
        before = path.read_bytes()
        assert log.finish() is False  # Windows refuses to replace the held file
        assert path.read_bytes() == before
        text = caplog.text
        assert f"{path}: is open in another program" in text and "recover" in text
        assert len(list(journal_dir(path).glob("trial-*.npz"))) == 3
        assert not list(tmp_path.glob("*.writing-*"))  # the temp version was removed
        reader.close()
        rep = recover(path)  # the next command publishes it
        assert rep.action == "appended" and rep.n_trials == 3
    _plain_h5py_equals(path, trials)


def test_a_scanner_holding_the_file_briefly_is_waited_for(tmp_path):
    path = tmp_path / "W.h5"
    path.write_bytes(b"old")
    with emulate_windows():
        code = ("import sys, time; f = open(sys.argv[1], 'rb'); print('x', flush=True); "
                "time.sleep(0.15)")
        proc = subprocess.Popen([sys.executable, "-c", code, str(path)],
                                stdout=subprocess.PIPE, text=True)
        assert proc.stdout.readline().strip() == "x"
        publish_image(path, b"new\n\x0a")  # refused while held, then retried
        proc.wait(timeout=30)
    assert path.read_bytes() == b"new\n\n"  # and binary: no \r added


def test_a_held_file_past_the_retries_is_one_line_naming_it(tmp_path):
    path = tmp_path / "W.h5"
    path.write_bytes(b"old")
    with emulate_windows(), open(path, "rb"), pytest.raises(FileHeldError) as err:
        publish_image(path, b"new", delays_s=FAST)
    text = str(err.value)
    assert text.startswith(f"{path}: is open in another program") and "\n" not in text
    assert path.read_bytes() == b"old" and not list(tmp_path.glob("*.writing-*"))


def test_posix_does_not_retry_a_refused_replace(tmp_path, monkeypatch):
    calls = []

    def refuse(src, dst):
        calls.append(dst)
        raise PermissionError(13, "Permission denied")
    monkeypatch.setattr(pub.os, "replace", refuse)
    with os_platform.forced("posix"), pytest.raises(pub.SessionWriteError) as err:
        publish_image(tmp_path / "x.h5", b"data")
    assert len(calls) == 1 and not isinstance(err.value, FileHeldError)
    calls.clear()
    with os_platform.forced("windows"), pytest.raises(FileHeldError):
        publish_image(tmp_path / "x.h5", b"data", delays_s=FAST)
    assert len(calls) == len(FAST) + 1


def test_a_killed_windows_session_recovers_its_streamed_trial_bit_for_bit(tmp_path):
    """partial.f64 and the published file are written through binary descriptors: under
    text mode every 0x0A byte would gain a 0x0D and the rows would shift."""
    path = tmp_path / "W.h5"
    t = _trial(0)
    with emulate_windows():
        assert not hasattr(os, "statvfs")  # free space through shutil.disk_usage
        log = _new_log(path)
        log.end_trial(_trial(1))
        log.begin_trial(Trial(sE=0.9, repeat=1, fs_Hz=2000.0, rE=[], I_ext_mA=[],
                              I_flex_mA=[], force_N=[], extra_attrs={"schedule_index": 5}))
        log.append_chunk(force_N=t.force_N, rE=t.rE, I_ext_mA=t.I_ext_mA,
                         I_flex_mA=t.I_flex_mA)
        log.close(publish=False)  # killed: the file holds the calibration only
        assert read_session(path).trials == []
        rep = recover(path)
    assert rep.partial_recovered and rep.partial_samples == len(t.force_N)
    s = read_session(path)
    kept = s.trials[-1]
    assert kept.status == "aborted" and kept.rE.tobytes() == t.rE.tobytes()
    assert kept.force_N.tobytes() == t.force_N.tobytes()


def test_a_damaged_entry_is_closed_before_recovery_sets_it_aside(tmp_path):
    """np.load of a damaged zip would keep its handle open in the exception: Windows then
    refuses to rename the entry (sharing violation) exactly when recovery needs to."""
    path = tmp_path / "W.h5"
    with emulate_windows():
        log = _new_log(path)
        for i in range(3):
            log.end_trial(_trial(i))
        log.close()
        entry = journal_dir(path) / "trial-0002.npz"
        entry.write_bytes(entry.read_bytes()[:-100])  # truncated: the zip directory is gone
        rep = recover(path)
        assert "trial-0002.npz (unreadable" in rep.summary()
        assert list(journal_dir(path).glob("unreadable-trial-0002.npz.at-*"))
        assert load_trial_npz(entry).extra_attrs["schedule_index"] == 1  # from the file
