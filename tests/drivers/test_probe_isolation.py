"""``nmsid probe`` checks each device on its own (issue 16): the fakes are made to fail one
device at a time; that device is one FAILED line, the others are still checked, exit 1."""

from __future__ import annotations

import pytest

from nmsid.cli import main
from nmsid.drivers.fake_hardware import load_fake


def _unplug_stimulator(monkeypatch):
    mcs = load_fake("fake_mcs_usb")
    real = mcs.install
    monkeypatch.setattr(mcs, "install", lambda bench=None, hardware=None, modules=None:
                        real(bench=bench, hardware=[], modules=modules))  # no STG on USB


def _unplug_caio(monkeypatch):
    caio = load_fake("fake_caio")
    real = caio.FakeCaioLibrary.__init__

    def init(self, *a, **kw):
        real(self, *a, **kw)
        self.plugged = False  # AioInit: AIO_ERR_DLL_DEVICE_NAME

    monkeypatch.setattr(caio.FakeCaioLibrary, "__init__", init)


def _unplug_leptrino(monkeypatch):
    emu = load_fake("leptrino_emulator")
    real = emu.LeptrinoEmulator.__enter__

    def enter(self):
        real(self)
        self.unplug()  # the port vanishes: opening it fails
        return self

    monkeypatch.setattr(emu.LeptrinoEmulator, "__enter__", enter)


def _unplug_estop(monkeypatch):
    from nmsid.drivers import estop_switch
    from nmsid.drivers.errors import DeviceNotFound

    def fail(self):
        raise DeviceNotFound("cannot open serial port 'COM7' for the E-stop switch "
                             "(estop.port): no such device")

    monkeypatch.setattr(estop_switch.SerialEStop, "open", fail)


CASES = [("caio", _unplug_stimulator, "stimulator", "acquisition: 2000 Hz"),
         ("caio", _unplug_caio, "acquisition", "serial: 4002-0001"),
         ("leptrino", _unplug_leptrino, "acquisition", "E-stop switch: released"),
         ("caio", _unplug_estop, "E-stop switch", "samples: force mean")]


@pytest.mark.parametrize("kind, unplug, device, still_checked", CASES,
                         ids=[f"{c[0]}-{c[2]}" for c in CASES])
def test_one_unreachable_device_is_one_line_and_the_others_are_checked(
        write_hw_config, tmp_path, capsys, monkeypatch, kind, unplug, device, still_checked):
    unplug(monkeypatch)
    fs = 1200.0 if kind == "leptrino" else 2000.0
    path = write_hw_config(tmp_path / "hw.toml", kind=kind, fs_Hz=fs)
    assert main(["probe", "--hw-config", str(path), "--samples", "20"]) == 1
    out = capsys.readouterr().out
    failed = [line for line in out.splitlines() if ": FAILED: " in line]
    assert len(failed) == 1 and failed[0].startswith(f"{device}: FAILED: ")
    assert still_checked in out
    assert out.rstrip().splitlines()[-1] == f"probe: 1 device(s) failed: {device}"


def test_old_firmware_leptrino_with_random_reserved_bits_probes_clean(
        write_hw_config, tmp_path, capsys, monkeypatch):
    """Done-when of issue 16: no rate field, reserved status bits at random: no error, no
    flag, and its force is read."""
    emu = load_fake("leptrino_emulator")
    real = emu.LeptrinoEmulator.__init__

    def init(self, *a, **kw):
        real(self, *a, **{**kw, "rate_text": None, "reserved_bits_random": True})

    monkeypatch.setattr(emu.LeptrinoEmulator, "__init__", init)
    path = write_hw_config(tmp_path / "hw.toml", kind="leptrino", fs_Hz=1200.0)
    assert main(["probe", "--hw-config", str(path), "--samples", "200"]) == 0
    out = capsys.readouterr().out
    assert "(no rate stated: the rate is measured)" in out
    assert "acquisition: 1200 Hz" in out
    assert "200 samples: force mean" in out
    assert "flag:" not in out and "FAILED" not in out
    assert out.rstrip().splitlines()[-1] == "probe: OK"


# -- a vendor library that aborts in native code (issue 37 item 8) ------------------------
def test_a_native_abort_is_that_devices_failure_and_the_others_still_print(
        write_hw_config, tmp_path):
    """Real devices (no fakes): pythonnet's ``clr`` aborts the process when imported, as
    McsUsbNet does under mono. The probe itself runs in a child here, so today's
    single-process probe shows what it would do: die, printing nothing of the others."""
    import os
    import subprocess
    import sys
    lib = tmp_path / "abortlib"
    lib.mkdir()
    for name in ("clr.py", "pythonnet.py"):
        (lib / name).write_text("import os\nos.abort()\n", encoding="utf-8")
    path = write_hw_config(tmp_path / "hw.toml", kind="caio", fs_Hz=2000.0, fake=False)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(lib), *filter(None, [os.environ.get("PYTHONPATH")])])}
    proc = subprocess.run([sys.executable, "-m", "nmsid", "probe", "--hw-config", str(path)],
                          capture_output=True, text=True, timeout=600, env=env,
                          cwd=str(tmp_path))
    out = proc.stdout
    failed = {line.split(": FAILED: ")[0]: line for line in out.splitlines()
              if ": FAILED: " in line}
    assert "ended abnormally" in failed.get("stimulator", ""), out + proc.stderr
    assert "SIGABRT" in failed["stimulator"] or "exit status" in failed["stimulator"]
    # the others were still checked, each its own line (no hardware here: each fails too)
    assert set(failed) == {"stimulator", "acquisition", "E-stop switch"}, out
    assert out.rstrip().splitlines()[-1].startswith("probe: 3 device(s) failed")
    assert proc.returncode == 1


def test_run_isolated_reports_a_check_that_aborts(capsys):
    from nmsid.cli.probe_command import run_isolated
    problem = run_isolated("test device", [], target="os:abort", timeout_s=120)
    assert problem.startswith("its check ended abnormally")
    ok = run_isolated("test device", ["x"], target="os.path:basename", timeout_s=120)
    assert ok == "x"      # a check's own problem text comes back as it is
