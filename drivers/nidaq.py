"""NI DAQ (any DAQmx device with analog inputs) through nidaqmx, as the alternative A/D.

Uses the documented nidaqmx-python API: ``nidaqmx.Task``,
``task.ai_channels.add_ai_voltage_chan(physical_channel, terminal_config=..., min_val,
max_val)``, ``task.timing.cfg_samp_clk_timing(rate, sample_mode=AcquisitionType.CONTINUOUS,
samps_per_chan=buffer)``, ``task.timing.samp_clk_rate`` (the rate really used),
``task.triggers.start_trigger.cfg_dig_edge_start_trig(source, trigger_edge=Edge.RISING)`` /
``disable_start_trig()``, ``task.register_every_n_samples_acquired_into_buffer_event(n,
callback)`` with ``callback(task_handle, every_n_samples_event_type, number_of_samples,
callback_data) -> 0``, and
``nidaqmx.stream_readers.AnalogMultiChannelReader(task.in_stream).read_many_sample(data,
number_of_samples_per_channel=n, timeout=...)`` into a (channels, n) float64 array.

Acquisition: continuous, hardware-timed at ``fs_Hz`` (2000 Hz), started by the rising edge
of the stimulator's sync output on a PFI line (``start_trigger``), so sample 0 is
stimulation onset; the sync is also recorded on an analog channel. The driver's callback
(NI's thread) reads every ``fs_Hz / reads_per_s`` samples (about 10 reads a second) into a
queue; :meth:`NidaqAcquisition.read` takes chunks from it. A read error from DAQmx that
means samples were lost (:data:`OVERRUN_CODES`: -200279, -200361, -200010, -200222 and
-200019 ADC overrun) becomes ``overrun`` with the DAQmx message; any other failure in the
callback (including -200141, ``CounterOverflow``, which is not a buffer overrun) becomes
``sensor_fault``. Code names: NI's ``NIDAQmx.h`` error list (as in nidaqmx-python's
``error_codes.DAQmxErrors``).

Buffer: DAQmx refuses to start a continuous task whose buffer is not a whole multiple of
the Every N Samples interval (-200877, ``BufferSizeNotMultipleOfEveryNSampsEventInterval
WhenDMA``). The driver reads back the COERCED sample rate (``timing.samp_clk_rate``),
derives the callback block from it, and sizes the buffer as a whole number of blocks
(timing configured once more with that size), so any ``reads_per_s`` works.

Aggregate rate: a multiplexed device converts every channel of a sample within the sample
period, so channels x rate may not exceed the device's ``ai_max_multi_chan_rate``
(nidaqmx ``Device`` property; NI in nidaqmx-python issue #349); DAQmx itself only warns
(200012) and delivers unsettled samples, so :meth:`NidaqAcquisition.configure` refuses it
first, naming the rate and the channels (not for simultaneous-sampling devices,
``ai_simultaneous_sampling_supported``).

Multiplexed conversion: the channels of one sample are converted one after the other at
the AI convert clock, read back as ``timing.ai_conv_rate``; channel k is sampled
``k / ai_conv_rate`` after the sample clock edge (:meth:`NidaqAcquisition.sample_delay_s`,
used by the dry run's onset figure). The dry run's monitor: with a calibration whose
``monitor_channel`` is set the chunk also carries that channel's volts (``ForceChunk.monitor``).

USB glitch: :meth:`NidaqAcquisition.reconnect` closes the old task and builds a new one.
"""

from __future__ import annotations

import logging
import os
import queue
import re
import uuid
from types import SimpleNamespace
from typing import Any

import numpy as np

from nmsid.drivers.analog_force import AnalogSensor, NoLoadTare, convert_block, measure_no_load
from nmsid.drivers.errors import (
    DeviceError,
    DeviceNotFound,
    HardwareConfigError,
    VendorLibraryMissing,
)
from nmsid.drivers.interfaces import AcquisitionFlags, ForceChunk

log = logging.getLogger(__name__)

OVERRUN_CODES = {
    -200279,  # SamplesNoLongerAvailable: the buffer was overwritten before it was read
    -200361,  # InputFIFOOverflow2: onboard memory overflow
    -200010,  # InputFIFOOverflow
    -200222,  # AcqStoppedToPreventInputBufferOverwrite
    -200019,  # ADCOverrun: a conversion started before the previous one was complete
}
"""DAQmx errors that mean samples were lost (NIDAQmx.h names)."""
COUNTER_OVERFLOW = -200141
"""``CounterOverflow``: a counter task's counter wrapped; not a buffer overrun."""
TERMINAL_CONFIGS = ("DEFAULT", "RSE", "NRSE", "DIFF", "PSEUDO_DIFF")


def _channel_order(name: str) -> tuple[int, str]:
    tail = name.rsplit("ai", 1)[-1]
    return (int(tail) if tail.isdigit() else 1 << 30, name)


_PFI_OF_PORT = {1: 0, 2: 8}
"""NI M- and X-series pinouts: "PFI 0/P1.0" .. "PFI 7/P1.7", "PFI 8/P2.0" .. "PFI 15/P2.7":
port 1 and port 2 lines are the PFI pins (port 0 lines are separate)."""


def shared_pin(estop_line: str, start_trigger: str) -> str:
    """A description if the E-stop's digital line and the start trigger's PFI terminal are
    the SAME pin (M/X-series pinout, :data:`_PFI_OF_PORT`), else ``""``.

    ``estop_line`` as ``Dev1/port1/line0``; ``start_trigger`` as ``/Dev1/PFI0``.
    """
    m_line = re.fullmatch(r"/?([^/]+)/port(\d+)/line(\d+)", estop_line.strip(), re.I)
    m_pfi = re.fullmatch(r"/?([^/]+)/PFI(\d+)", start_trigger.strip(), re.I)
    if not m_line or not m_pfi or m_line.group(1) != m_pfi.group(1):
        return ""
    port, line = int(m_line.group(2)), int(m_line.group(3))
    if port in _PFI_OF_PORT and _PFI_OF_PORT[port] + line == int(m_pfi.group(2)):
        return (f"estop.line {estop_line!r} and acquisition.nidaq.start_trigger "
                f"{start_trigger!r} are the same pin (PFI {m_pfi.group(2)}/P{port}.{line} on "
                "NI M- and X-series devices): the stimulator's sync would read as the E-stop "
                "and the E-stop as a start; wire the E-stop to a port 0 line")
    return ""


def load_nidaqmx() -> SimpleNamespace:
    """Import nidaqmx lazily; one clear line if it is missing."""
    try:
        import nidaqmx  # noqa: PLC0415
        from nidaqmx import constants, errors, stream_readers  # noqa: PLC0415
    except ImportError:
        raise VendorLibraryMissing(
            "the Python package nidaqmx", "the NI DAQ acquisition",
            "install it with: pip install 'nmsid[nidaq]' and install NI-DAQmx "
            "(python -m nidaqmx installdriver)") from None
    return SimpleNamespace(nidaqmx=nidaqmx, constants=constants, errors=errors,
                           stream_readers=stream_readers)


def buffer_samples(fs_Hz: float, buffer_s: float, n_block: int) -> int:
    """Input buffer per channel: at least ``buffer_s`` seconds (and 1000 samples) at the
    coerced rate ``fs_Hz``, rounded UP to a whole number of callback blocks (DAQmx -200877
    otherwise)."""
    want = max(fs_Hz * buffer_s, 1000.0)
    return int(-(-want // n_block)) * n_block


class NidaqAcquisition:
    """:class:`~nmsid.drivers.interfaces.ForceAcquisition` over an NI DAQmx device.

    Parameters
    ----------
    calibration : AnalogCalibration or DynamometerCalibration
        A/D channel index k is ``<device>/ai<k>``.
    device : str
        DAQmx device name (``Dev1``).
    start_trigger : str
        Terminal carrying the stimulator's sync; ``""`` (default) is the device's own
        ``/<device>/PFI0`` (not ``/Dev1/PFI0`` whatever the device is called).
    terminal_config : str
        One of ``DEFAULT``, ``RSE``, ``NRSE``, ``DIFF``, ``PSEUDO_DIFF``.
    range_V : float
        Symmetric input range (``min_val = -range_V``, ``max_val = range_V``).
    reads_per_s : float
        Callback rate (every ``fs_Hz / reads_per_s`` samples).
    api : namespace, optional
        The loaded nidaqmx names (tests pass the fake).
    """

    def __init__(self, calibration: AnalogSensor, *, device: str = "Dev1",
                 start_trigger: str = "", terminal_config: str = "DIFF",
                 range_V: float = 10.0, reads_per_s: float = 10.0, buffer_s: float = 5.0,
                 api=None):
        if terminal_config not in TERMINAL_CONFIGS:
            raise HardwareConfigError(f"acquisition.nidaq.terminal_config {terminal_config!r} "
                                      f"is not one of {TERMINAL_CONFIGS}")
        if not range_V > 0:
            raise HardwareConfigError(f"acquisition.nidaq.range_V must be > 0, got {range_V!r}")
        if not reads_per_s > 0:
            raise HardwareConfigError("acquisition.nidaq.reads_per_s must be > 0, got "
                                      f"{reads_per_s!r}")
        self.cal = calibration
        for warning in calibration.implausible():
            log.warning("%s", warning)
        self.device = device
        self.start_trigger = start_trigger or f"/{device}/PFI0"
        self.terminal_config = terminal_config
        self.range_V = float(range_V)
        self.reads_per_s = reads_per_s
        self.buffer_s = buffer_s
        self._api = api
        self._task = None
        self._reader: Any = None            # nidaqmx's AnalogMultiChannelReader, once started
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._fs_Hz = 0.0
        self._n_block = 0
        self._conv_Hz = 0.0
        self._buffer = 0
        self._running = False
        self._index = 0
        self._remaining: int | None = None
        self._generation = 0
        self._tare = NoLoadTare()
        """No-load voltages, measured before a session's first block and after each rest
        (CFS manual 4.2; :mod:`nmsid.drivers.analog_force`)."""
        self._capture: list[np.ndarray] | None = None

    @property
    def fs_Hz(self) -> float:
        return self._fs_Hz

    @property
    def api(self):
        if self._api is None:
            self._api = load_nidaqmx()
        return self._api

    def _channels(self) -> list[str]:
        return [f"{self.device}/ai{k}" for k in range(self.cal.n_channels)]

    def configure(self, fs_Hz: float) -> float:
        """Build the task (channels, continuous timing, callback); return the real rate."""
        if not fs_Hz > 0:
            raise HardwareConfigError(f"acquisition.fs_Hz must be > 0, got {fs_Hz!r}")
        self.close()
        api = self.api
        c = api.constants
        self._check_aggregate(fs_Hz)
        self._check_physical_channels()
        # a unique name: DAQmx refuses a second task of the same name (-200089), e.g. one a
        # crashed session left in this process or another nmsid holds
        name = f"nmsid-force-{os.getpid()}-{uuid.uuid4().hex[:8]}"
        try:
            task = api.nidaqmx.Task(name)
        except api.errors.DaqError as exc:
            raise DeviceError(f"DAQmx could not create a task: {exc}") from None
        try:
            for name in self._channels():
                task.ai_channels.add_ai_voltage_chan(
                    name, terminal_config=getattr(c.TerminalConfiguration, self.terminal_config),
                    min_val=-self.range_V, max_val=self.range_V)
            task.timing.cfg_samp_clk_timing(
                fs_Hz, sample_mode=c.AcquisitionType.CONTINUOUS,
                samps_per_chan=int(max(fs_Hz * self.buffer_s, 1000)))
            self._fs_Hz = float(task.timing.samp_clk_rate)  # coerced by the device
            self._n_block = max(1, int(round(self._fs_Hz / self.reads_per_s)))
            self._buffer = buffer_samples(self._fs_Hz, self.buffer_s, self._n_block)
            task.timing.cfg_samp_clk_timing(
                self._fs_Hz, sample_mode=c.AcquisitionType.CONTINUOUS,
                samps_per_chan=self._buffer)
            if abs(float(task.timing.samp_clk_rate) - self._fs_Hz) > 1e-9 * self._fs_Hz:
                raise DeviceError(f"NI DAQ {self.device!r} changed its sample rate from "
                                  f"{self._fs_Hz} to {task.timing.samp_clk_rate} Hz when "
                                  "the buffer was resized")
            try:
                self._conv_Hz = float(task.timing.ai_conv_rate)
            except Exception as exc:  # a device without a convert clock (simultaneous)
                log.info("NI DAQ %s: no AI convert clock to read (%s)", self.device, exc)
                self._conv_Hz = 0.0
            self._reader = api.stream_readers.AnalogMultiChannelReader(task.in_stream)
            task.register_every_n_samples_acquired_into_buffer_event(self._n_block,
                                                                     self._on_samples)
        except api.errors.DaqError as exc:
            task.close()
            raise DeviceNotFound(f"NI DAQ {self.device!r}: {exc} (check acquisition.nidaq "
                                 "device and channels in NI MAX)") from None
        self._task = task
        return self._fs_Hz

    def _check_physical_channels(self) -> None:
        """Refuse channels the device does not have, or a terminal configuration a channel
        does not support, before any task is made (nidaqmx ``Device.ai_physical_chans``,
        ``PhysicalChannel.ai_term_cfgs``; on M-series boards aiK pairs with aiK+8 in DIFF,
        so ai8 .. ai15 have no DIFF)."""
        try:
            dev = self.api.nidaqmx.system.System.local().devices[self.device]
            phys = {str(c.name): c for c in dev.ai_physical_chans}
        except Exception as exc:  # not readable: DAQmx judges when the task is built
            log.info("NI DAQ %s: physical channels not readable (%s)", self.device, exc)
            return
        wanted = self._channels()
        missing = [n for n in wanted if n not in phys]
        if missing:
            have = ", ".join(sorted(phys, key=_channel_order)) or "none"
            raise HardwareConfigError(
                f"NI DAQ {self.device!r} has no {', '.join(missing)} (the sensor map scans "
                f"ai0 .. ai{len(wanted) - 1}); it has {have}; fix [sensor.channels] / "
                "sync_channel or acquisition.nidaq.device")
        if self.terminal_config == "DEFAULT":
            return
        term = getattr(self.api.constants.TerminalConfiguration, self.terminal_config)
        bad = []
        for n in wanted:
            try:
                cfgs = list(phys[n].ai_term_cfgs)
            except Exception:  # property not available: DAQmx judges
                return
            if term not in cfgs:
                bad.append(f"{n} ({'/'.join(getattr(c, 'name', str(c)) for c in cfgs)})")
        if bad:
            raise HardwareConfigError(
                f"acquisition.nidaq.terminal_config = {self.terminal_config!r} is not "
                f"supported by {', '.join(bad)} on {self.device!r}; wire the sensor to "
                "channels that support it or choose another terminal configuration")

    def _check_aggregate(self, fs_Hz: float) -> None:
        """Refuse channels x rate above the device's multichannel (aggregate) rate."""
        try:
            dev = self.api.nidaqmx.system.System.local().devices[self.device]
            top = float(dev.ai_max_multi_chan_rate)
            simultaneous = bool(getattr(dev, "ai_simultaneous_sampling_supported", False))
        except Exception as exc:  # not readable: DAQmx will judge at start
            log.info("NI DAQ %s: no multichannel rate to check (%s)", self.device, exc)
            return
        n = self.cal.n_channels
        if not simultaneous and n > 1 and n * fs_Hz > top * (1 + 1e-9):
            raise HardwareConfigError(
                f"NI DAQ {self.device!r}: {fs_Hz:g} Hz over {n} channels (ai0 .. ai{n - 1}) "
                f"needs {n * fs_Hz / 1000:g} kS/s; the device converts at most "
                f"{top / 1000:g} kS/s over all channels, i.e. {top / n:g} Hz for {n} channels; "
                "wire the channels to lower inputs or lower the rate")

    def _on_samples(self, task_handle, every_n_samples_event_type, number_of_samples,
                    callback_data):
        """DAQmx callback (NI's thread): read one block into the queue. Must return 0."""
        gen = self._generation
        data = np.zeros((self.cal.n_channels, number_of_samples))
        try:
            self._reader.read_many_sample(data, number_of_samples_per_channel=number_of_samples,
                                          timeout=0.0)
            self._queue.put((gen, data, None))
        except Exception as exc:  # DaqReadError and anything else: reported, never raised
            code = getattr(exc, "error_code", None)
            self._queue.put((gen, None, (code, str(exc).splitlines()[0] if str(exc) else
                                         type(exc).__name__)))
        return 0

    def start(self, n_samples: int | None = None, *, triggered: bool = True) -> None:
        """The trial's block; first the no-load voltages, when due (the tare)."""
        if self._task is None:
            raise DeviceError("configure(fs_Hz) must be called before start()")
        measure_no_load(self, f"NI DAQ {self.device!r}")
        self._start_block(n_samples, triggered=triggered)

    def _start_block(self, n_samples: int | None, *, triggered: bool) -> None:
        api, task = self.api, self._task
        assert task is not None     # start() checked it
        trig = task.triggers.start_trigger
        if triggered:
            trig.cfg_dig_edge_start_trig(self.start_trigger,
                                         trigger_edge=api.constants.Edge.RISING)
        else:
            trig.disable_start_trig()
        self._generation += 1
        self._index = 0
        self._remaining = n_samples
        try:
            task.start()
        except api.errors.DaqError as exc:
            raise DeviceError(f"NI DAQ {self.device!r} did not start: {exc}") from None
        self._running = True

    def read(self, timeout_s: float) -> ForceChunk | None:
        if not self._running:
            return None
        while True:
            try:
                gen, data, err = self._queue.get(timeout=max(timeout_s, 0.0))
            except queue.Empty:
                return None
            if gen == self._generation:
                break  # blocks of an earlier trial are dropped
        if err is not None:
            code, text = err
            overrun = code in OVERRUN_CODES
            if code == COUNTER_OVERFLOW:
                text = f"counter overflow (not a buffer overrun): {text}"
            return ForceChunk(start_index=self._index, force_N=np.zeros(0),
                              wrench=np.zeros((0, 6)) if self.cal.full_wrench else None,
                              sync=np.zeros(0) if self.cal.sync_channel is not None else None,
                              monitor=np.zeros(0) if self.cal.monitor_channel is not None
                              else None,
                              flags=AcquisitionFlags(overrun=overrun, sensor_fault=not overrun,
                                                     detail=f"DAQmx error {code}: {text}"))
        if self._remaining is not None:
            data = data[:, :self._remaining]
            self._remaining -= data.shape[1]
        n = data.shape[1]
        if self._capture is not None:
            self._capture.append(data.T)
        block = convert_block(data.T, self.cal, self.range_V, tare_wrench=self._tare.wrench)
        flags = AcquisitionFlags(over_range=block.saturated,
                                 detail=f"sensor output at the edge of +/-{self.range_V:g} V"
                                 if block.saturated else "")
        chunk = ForceChunk(start_index=self._index, force_N=block.force_N, wrench=block.wrench,
                           sync=block.sync_V, flags=flags, monitor=block.monitor_V)
        self._index += n
        return chunk

    def sample_delay_s(self, channel: int) -> float:
        """How long after the sample clock edge ``channel`` (``ai<channel>``, the
        ``channel``-th of the task) is converted: ``channel / ai_conv_rate``; 0 if the device
        reported no convert clock."""
        return channel / self._conv_Hz if self._conv_Hz > 0 else 0.0

    def stop(self) -> None:
        if self._running:
            self._tare.stopped()
        self._stop_block()

    def _stop_block(self) -> None:
        if self._task is not None and self._running:
            self._running = False
            try:
                self._task.stop()
            except Exception as exc:
                log.warning("NI DAQ stop failed: %s", exc)

    def device_fault(self) -> str:
        """Between trials: "" if the task answers ``is_task_done()``, else the DAQmx error.

        (That a task on a removed USB device answers with an error, e.g. -201003, is what
        the fake models; not verified on hardware.)
        """
        if self._task is None:
            return f"NI DAQ {self.device!r}: no task (configure() not called)"
        try:
            self._task.is_task_done()
        except Exception as exc:
            code = getattr(exc, "error_code", "")
            return f"NI DAQ {self.device!r} does not answer: DAQmx error {code}: " \
                   f"{str(exc).splitlines()[0] if str(exc) else type(exc).__name__}"
        return ""

    def reconnect(self, fs_Hz: float) -> float:
        """After a USB glitch: close the old task, build and configure a new one.

        Raises
        ------
        DeviceNotFound, DeviceError
            If the device is still not reachable.
        """
        self._tare.forget()
        return self.configure(fs_Hz)

    def close(self) -> None:
        task, self._task = self._task, None
        self._running = False
        if task is not None:
            try:
                task.close()
            except Exception as exc:
                log.warning("NI DAQ close failed: %s", exc)

    def describe(self) -> dict:
        info = {"device": self.device, "channels": self._channels(),
                "start_trigger": self.start_trigger, "fs_Hz": self._fs_Hz,
                "samples_per_read": self._n_block, "buffer_samples": self._buffer}
        try:
            dev = self.api.nidaqmx.system.System.local().devices[self.device]
            info.update(product=str(dev.product_type), serial=str(dev.serial_num))
        except Exception as exc:
            info["product"] = f"unknown ({exc})"
        return info
