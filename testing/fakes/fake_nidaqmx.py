"""A fake ``nidaqmx`` package: the calls ``drivers.nidaq`` and ``drivers.estop_switch`` make.

Modules ``nidaqmx``, ``nidaqmx.constants``, ``nidaqmx.errors``, ``nidaqmx.stream_readers``,
``nidaqmx.system`` with: ``Task(name)`` (context manager, ``ai_channels.add_ai_voltage_chan``,
``di_channels.add_di_chan``, ``timing.cfg_samp_clk_timing``, ``timing.samp_clk_rate``,
``triggers.start_trigger.cfg_dig_edge_start_trig`` / ``disable_start_trig``,
``register_every_n_samples_acquired_into_buffer_event``, ``start``, ``stop``, ``close``,
``read`` for digital lines, ``in_stream``); ``AnalogMultiChannelReader.read_many_sample``
(fills a C-contiguous float64 (channels, n) array, like the real one checks);
``AcquisitionType``, ``Edge``, ``TerminalConfiguration``, ``READ_ALL_AVAILABLE``;
``DaqError`` / ``DaqReadError`` with ``error_code``; ``system.System.local().devices``.

Like DAQmx, the callback runs on a separate thread once per ``n`` acquired samples; the
acquisition is hardware-timed on the :class:`bench.FakeBench` clock and, with a digital
edge start trigger, starts at the fake stimulator's sync edge. ``inject_read_error`` makes
the next read fail with that DAQmx error (e.g. -200279 samples no longer available,
-200019 ADC overrun), with DAQmx's message.

DAQmx behaviour modelled from NI's documentation and error list (``NIDAQmx.h`` /
nidaqmx-python ``error_codes.DAQmxErrors``), not from ``drivers.nidaq``:

* The sample clock is derived from a timebase (``timebase_Hz`` of the device entry,
  20 MHz by default as on M/X series boards), so the rate is COERCED to
  ``timebase / round(timebase / rate)``; ``timing.samp_clk_rate`` reads it back.
* Multiplexed conversion: the channels of one sample are converted one after the other at
  the AI convert clock (``timing.ai_conv_rate``, nidaqmx's property for "the rate at which
  to clock the analog-to-digital converter" of multiplexed devices), so the i-th channel
  of the task is sampled ``i / ai_conv_rate`` after the sample clock edge. The fake's
  rate is the device entry's ``ai_conv_rate_Hz`` (80 kHz by default: a stand-in, the
  real default depends on the device and the sample rate); when the channels do not fit
  into one sample period at that rate, the conversions are spread over it (channels x
  sample rate), all channels having to be converted within the sample period (NI's
  answer in nidaqmx-python issue #349: "you have to convert all 3 channels in that 2 us
  sample period"). The device's ``ai_max_multi_chan_rate`` (nidaqmx's
  ``Device.ai_max_multi_chan_rate``, the aggregate rate of a multiplexed device; 400
  kS/s for the USB-6212 by default) is the most it converts; asking more makes DAQmx
  warn (200012, "Clock rate specified exceeds the maximum conversion rate of the ADC",
  as quoted in JaneliaSciComp/WaveSurfer issue #85) and the samples are not settled:
  the fake warns likewise.
* Starting a continuous task with an Every N Samples event whose buffer
  (``samps_per_chan``) is not a multiple of N fails with -200877
  (``BufferSizeNotMultipleOfEveryNSampsEventIntervalWhenDMA``).
* -200019 (``ADCOverrun``): a conversion was attempted before the previous one was
  complete; samples are lost. -200141 is ``CounterOverflow`` (counter tasks only).
* ``unplug()`` / ``replug()``: while unplugged, starting a task fails with -201003 (device
  cannot be accessed) and a running task's next read fails with it; a task created before
  the glitch stays dead after ``replug()`` (a new task must be made), and
  ``is_task_done()`` on a dead task raises -201003 (an assumption, not verified on
  hardware).
"""

from __future__ import annotations

import enum
import sys
import threading
import types
import warnings
from typing import Any

import numpy as np


class DaqError(Exception):
    def __init__(self, message, error_code, task_name=""):
        super().__init__(message)
        self.error_code = error_code


class DaqWarning(Warning):
    """DAQmx's positive status codes, issued with :func:`warnings.warn` as nidaqmx does."""

    def __init__(self, message, error_code):
        super().__init__(message)
        self.error_code = error_code


class DaqReadError(DaqError):
    pass


MESSAGES = {
    # DAQmx error texts as DAQmx prints them (nidaqmx error_codes.DAQmxErrors names in
    # brackets): PhysicalChanDoesNotExist, InvalidAttributeValue, TaskNameConflict (the
    # "Task name specified conflicts with an existing task name" of -200089),
    # InvalidRoutingSourceTerminalName
    -200170: "Physical channel specified does not exist on this device.",
    -200077: "Requested value is not a supported value for this property. The property "
             "value may be invalid because it conflicts with another property.",
    -200089: "Task name specified conflicts with an existing task name.",
    -89125: "Source terminal to be routed could not be found on the device.",
    200012: "Clock rate specified exceeds the maximum conversion rate of the ADC.",
    -200279: "The application is not able to keep up with the acquisition. Attempted to "
             "read samples that are no longer available.",
    -200019: "ADC conversion attempted before the prior conversion was complete.",
    -200141: "Counter overflow.",
    -200361: "Onboard device memory overflow. Because of system and/or bus-bandwidth "
             "limitations, the driver could not read data from the device fast enough.",
    -200877: "Requested Every N Samples Event Interval is not supported for the given Data "
             "Transfer Mechanism and buffer size. To keep DMA or USB Bulk as the Data "
             "Transfer Mechanism, make the buffer size an even multiple of the Every N "
             "Samples Event Interval.",
    -201003: "Device cannot be accessed. Possible causes: Device is no longer present in "
             "the system.",
}


class AcquisitionType(enum.Enum):
    FINITE = 10178
    CONTINUOUS = 10123
    HW_TIMED_SINGLE_POINT = 12522


class Edge(enum.Enum):
    RISING = 10280
    FALLING = 10171


class TerminalConfiguration(enum.Enum):
    DEFAULT = -1
    RSE = 10083
    NRSE = 10078
    DIFF = 10106
    PSEUDO_DIFF = 12529


READ_ALL_AVAILABLE = -1


class _Devices:
    def __init__(self, state):
        self.state = state

    def __getitem__(self, name):
        if name not in self.state.devices:
            raise DaqError(f"Device identifier is invalid: {name}", -200220)
        entry = {"ai_max_multi_chan_rate": 400e3, "ai_simultaneous_sampling_supported": False,
                 **self.state.devices[name]}   # the USB-6212's data sheet: 400 kS/s aggregate
        entry.setdefault("ai_physical_chans", physical_channels(name, entry.pop("n_ai", 16)))
        return types.SimpleNamespace(name=name, **entry)

    def __iter__(self):
        return iter(self[n] for n in self.state.devices)


def physical_channels(device: str, n_ai: int = 16) -> list:
    """``Device.ai_physical_chans`` of an M-series device with ``n_ai`` single-ended
    inputs: ``PhysicalChannel.name`` ``Dev1/ai0`` ... and ``ai_term_cfgs`` (nidaqmx 1.x,
    "the terminal configurations supported by the channel"). NI's M-series pinout pairs
    aiK with aiK+8 for differential input: ai0..7 support RSE, NRSE and DIFF, ai8..15
    only RSE and NRSE."""
    T = TerminalConfiguration
    half = n_ai // 2
    return [types.SimpleNamespace(
        name=f"{device}/ai{k}",
        ai_term_cfgs=[T.RSE, T.NRSE, T.DIFF] if k < half else [T.RSE, T.NRSE])
        for k in range(n_ai)]


def sync_terminal(device: str) -> str:
    """Where the fake bench's STG sync is wired: the device entry's ``sync_terminal``,
    else ``/<device>/PFI0``."""
    entry = _State.devices.get(device, {})
    return entry.get("sync_terminal", f"/{device}/PFI0")


class _State:
    bench: Any = None          # the FakeBench the fake reads (None until one is wired)
    devices: dict = {}
    wiring: dict = {}
    di_lines: dict = {}
    tasks: list = []
    inject_read_error: int | None = None
    unplugged: bool = False
    generation: int = 0


class _Channels:
    def __init__(self, task, kind):
        self.task, self.kind, self.names = task, kind, []

    def add_ai_voltage_chan(self, physical_channel, name_to_assign_to_channel="",
                            terminal_config=TerminalConfiguration.DEFAULT, min_val=-5.0,
                            max_val=5.0, **kw):
        self._check(physical_channel)
        if not isinstance(terminal_config, TerminalConfiguration):
            raise TypeError("terminal_config must be a TerminalConfiguration")
        dev = _Devices(_State)[physical_channel.split("/")[0]]
        phys = {c.name: c for c in dev.ai_physical_chans}
        if physical_channel not in phys:
            raise DaqError(f"{MESSAGES[-200170]}\nPhysical Channel Name: {physical_channel}",
                           -200170)
        if terminal_config is not TerminalConfiguration.DEFAULT \
                and terminal_config not in phys[physical_channel].ai_term_cfgs:
            raise DaqError(f"{MESSAGES[-200077]}\nProperty: AI.TermCfg\nRequested Value: "
                           f"{terminal_config.name}\nChannel Name: {physical_channel}", -200077)
        if not min_val < max_val:
            raise DaqError("min_val must be below max_val", -200082)
        self.names.append(physical_channel)
        self.task.range_V = max(abs(min_val), abs(max_val))

    def add_di_chan(self, lines, name_to_assign_to_lines="", **kw):
        self._check(lines)
        self.names.append(lines)

    def _check(self, name):
        dev = name.split("/")[0]
        if dev not in _State.devices:
            raise DaqError(f"Device identifier is invalid: {dev}", -200220)


class _Timing:
    def __init__(self, task):
        self.task = task
        self.samp_clk_rate = 0.0
        self.ai_conv_rate = 0.0

    def cfg_samp_clk_timing(self, rate, source="", active_edge=Edge.RISING,
                            sample_mode=AcquisitionType.FINITE, samps_per_chan=1000):
        if not isinstance(sample_mode, AcquisitionType):
            raise TypeError("sample_mode must be an AcquisitionType")
        if not 0 < rate <= 250_000:
            raise DaqError(f"sample clock rate {rate} is out of range", -200077)
        dev = self.task.ai_channels.names[0].split("/")[0] if self.task.ai_channels.names \
            else ""
        base = float(_State.devices.get(dev, {}).get("timebase_Hz", 20e6))
        self.samp_clk_rate = base / max(1, round(base / rate))  # coerced, as DAQmx does
        self.task.mode = sample_mode
        self.task.buffer = int(samps_per_chan)
        self._convert_clock(dev)

    def _convert_clock(self, dev):
        """``ai_conv_rate`` as DAQmx would choose it (see the module docstring)."""
        entry = _State.devices.get(dev, {})
        n = max(1, len(self.task.ai_channels.names))
        if entry.get("ai_simultaneous_sampling_supported", False):
            self.ai_conv_rate = 0.0   # one ADC per channel: no convert clock, no skew
            return
        conv = float(entry.get("ai_conv_rate_Hz", 80e3))
        self.ai_conv_rate = max(conv, n * self.samp_clk_rate)  # all within one period
        top = float(entry.get("ai_max_multi_chan_rate", 400e3))
        if self.ai_conv_rate > top:
            warnings.warn(DaqWarning(f"{MESSAGES[200012]} (device {dev}: {n} channels x "
                                     f"{self.samp_clk_rate:g} Hz > {top:g} S/s)", 200012),
                          stacklevel=2)


class _StartTrigger:
    def __init__(self):
        self.source = None

    def cfg_dig_edge_start_trig(self, trigger_source, trigger_edge=Edge.RISING):
        if not isinstance(trigger_edge, Edge):
            raise TypeError("trigger_edge must be an Edge")
        parts = str(trigger_source).strip("/").split("/")
        if len(parts) != 2 or parts[0] not in _State.devices \
                or not parts[1].upper().startswith("PFI") or not parts[1][3:].isdigit() \
                or int(parts[1][3:]) > 15:
            raise DaqError(f"{MESSAGES[-89125]}\nSource Terminal: {trigger_source}", -89125)
        self.source = trigger_source

    def disable_start_trig(self):
        self.source = None


class Task:
    def __init__(self, new_task_name=""):
        if new_task_name and any(t.name == new_task_name and not t.closed
                                 for t in _State.tasks):
            raise DaqError(f"{MESSAGES[-200089]}\nTask Name: {new_task_name}", -200089)
        self.name = new_task_name
        self.ai_channels = _Channels(self, "ai")
        self.di_channels = _Channels(self, "di")
        self.timing = _Timing(self)
        self.triggers = types.SimpleNamespace(start_trigger=_StartTrigger())
        self.in_stream = types.SimpleNamespace(task=self)
        self.range_V = 10.0
        self.mode = AcquisitionType.FINITE
        self.buffer = 1000
        self.callback = None
        self.n_every = 0
        self.running = False
        self.closed = False
        self._thread = None
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._data = np.zeros((0, 0))
        self.generation = _State.generation
        _State.tasks.append(self)

    def _dead(self) -> bool:
        return _State.unplugged or self.generation != _State.generation

    def is_task_done(self):
        if self._dead() and self.ai_channels.names:
            raise DaqError(MESSAGES[-201003], -201003)
        return not self.running

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def register_every_n_samples_acquired_into_buffer_event(self, sample_interval, callback_method):
        if self.running:
            raise DaqError("cannot register an event while the task runs", -200986)
        self.n_every, self.callback = int(sample_interval), callback_method

    def start(self):
        if self.closed:
            raise DaqError("task closed", -200088)
        if self._dead() and self.ai_channels.names:
            raise DaqError(MESSAGES[-201003], -201003)
        if self.mode is AcquisitionType.CONTINUOUS and self.callback is not None \
                and self.buffer % self.n_every:
            raise DaqError(f"{MESSAGES[-200877]} Buffer size: {self.buffer}; Every N Samples "
                           f"Event Interval: {self.n_every}", -200877)
        self.running = True
        if not self.ai_channels.names:
            return
        self._stop.clear()
        self._t_call = _State.bench.now()
        self._t_first = None
        self._generated = 0
        self._data = np.zeros((len(self.ai_channels.names), 0))
        self._thread = threading.Thread(target=self._acquire, daemon=True)
        self._thread.start()

    def _acquire(self):
        bench, fs = _State.bench, self.timing.samp_clk_rate
        while not self._stop.is_set():
            bench.sleep(self.n_every / fs / 4)
            now = bench.now()
            if self._t_first is None:
                src = self.triggers.start_trigger.source
                if src is None:
                    self._t_first = self._t_call
                elif src.upper() != sync_terminal(
                        self.ai_channels.names[0].split("/")[0]).upper():
                    continue   # nothing wired to that terminal: the trigger never comes
                else:
                    t = bench.trigger_time()
                    if t is None or t < self._t_call:
                        continue
                    self._t_first = t
            due = int(np.floor((now - self._t_first) * fs)) + 1
            new = due - self._generated
            if new <= 0:
                continue
            t = self._t_first + (self._generated + np.arange(new)) / fs
            force = bench.force_N(t, fs)
            block = np.zeros((len(self.ai_channels.names), new))
            for i, name in enumerate(self.ai_channels.names):
                k = int(name.rsplit("ai", 1)[1])
                fn = _State.wiring.get(k)
                if fn is not None:  # converted one after the other (multiplexed ADC)
                    conv = self.timing.ai_conv_rate
                    block[i] = np.clip(fn(t + (i / conv if conv else 0.0), force),
                                       -self.range_V, self.range_V)
            self._generated = due
            with self._lock:
                self._data = np.concatenate([self._data, block], axis=1)
            while self.callback is not None and self._data.shape[1] >= self.n_every \
                    and not self._stop.is_set():
                self.callback(0, 1, self.n_every, None)

    def stop(self):
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2)
        self.running = False

    def close(self):
        self.stop()
        self.closed = True

    def read(self, number_of_samples_per_channel=-1, timeout=10.0):
        line = self.di_channels.names[0]
        value = _State.di_lines.get(line)
        if value is None:
            raise DaqError(f"physical channel {line} does not exist", -200170)
        if isinstance(value, Exception):
            raise value
        return bool(value)

    def _take(self, n):
        with self._lock:
            if self._dead():
                raise DaqReadError(MESSAGES[-201003], -201003)
            if _State.inject_read_error is not None:
                code, _State.inject_read_error = _State.inject_read_error, None
                self._data = self._data[:, n:]
                raise DaqReadError(MESSAGES.get(code, f"DAQmx error {code}"), code)
            out = self._data[:, :n]
            self._data = self._data[:, n:]
            return out


class AnalogMultiChannelReader:
    def __init__(self, task_in_stream):
        self.task = task_in_stream.task

    def read_many_sample(self, data, number_of_samples_per_channel=READ_ALL_AVAILABLE,
                         timeout=10.0):
        if not isinstance(data, np.ndarray) or data.dtype != np.float64 \
                or not data.flags["C_CONTIGUOUS"]:
            raise DaqError("data must be a C-contiguous numpy float64 array", -200229)
        n = number_of_samples_per_channel
        if data.shape != (len(self.task.ai_channels.names), n):
            raise DaqError(f"read array has shape {data.shape}, expected "
                           f"({len(self.task.ai_channels.names)}, {n})", -200229)
        block = self.task._take(n)
        data[:, :block.shape[1]] = block
        return block.shape[1]


def _module(name: str, **attrs: object) -> types.ModuleType:
    """A stand-in module ``name`` holding ``attrs``."""
    module = types.ModuleType(name)
    for key, value in attrs.items():
        setattr(module, key, value)
    return module


def install(bench=None, devices=None, wiring=None, di_lines=None, modules=None) -> dict:
    _State.bench = bench
    _State.devices = devices if devices is not None else {
        "Dev1": {"product_type": "USB-6212", "serial_num": 0x1A2B3C}}
    _State.wiring = wiring or {}
    _State.di_lines = di_lines if di_lines is not None else {}
    _State.tasks = []
    _State.inject_read_error = None
    _State.unplugged = False
    _State.generation = 0
    constants = _module("nidaqmx.constants", READ_ALL_AVAILABLE=READ_ALL_AVAILABLE,
                        **{c.__name__: c for c in (AcquisitionType, Edge, TerminalConfiguration)})
    errors = _module("nidaqmx.errors", DaqError=DaqError, DaqReadError=DaqReadError,
                     DaqWarning=DaqWarning)
    readers = _module("nidaqmx.stream_readers", AnalogMultiChannelReader=AnalogMultiChannelReader)
    system = _module("nidaqmx.system", System=types.SimpleNamespace(
        local=lambda: types.SimpleNamespace(devices=_Devices(_State))))
    root = _module("nidaqmx", Task=Task, constants=constants, errors=errors,
                   stream_readers=readers, system=system, DaqError=DaqError)
    mods = {"nidaqmx": root, "nidaqmx.constants": constants, "nidaqmx.errors": errors,
            "nidaqmx.stream_readers": readers, "nidaqmx.system": system}
    (sys.modules if modules is None else modules).update(mods)
    return mods


def unplug() -> None:
    """The USB device disappears: reads and starts fail with -201003; tasks made before
    stay dead."""
    _State.unplugged = True
    _State.generation += 1


def replug() -> None:
    _State.unplugged = False


def state() -> type[_State]:
    return _State
