"""A fake of Contec's CAIO library (caio.dll / libcaio.so) with ctypes calling conventions.

``FakeCaioLibrary`` has the vendor's function names; each is a callable with settable
``argtypes`` / ``restype`` like a ctypes foreign function, and it refuses to run until
``argtypes`` is declared. Arguments are converted with ``argtype.from_param`` exactly as
ctypes does (so passing a Python int where ``POINTER(c_long)`` is declared fails the same
way), then output parameters (``byref`` objects, arrays) are written in place. Return
value: 0 on success, a CAIO-style error code otherwise (``AioGetErrorString`` describes
it).

The fake device samples, on the :class:`bench.FakeBench` clock, the A/D channels wired by
``wiring`` (``{channel: callable(t_array, force_N_array) -> volts}``) into a FIFO of
``fifo_samples`` scans; an external start trigger waits for the fake stimulator's sync
edge; a FIFO that overflows sets ``AIS_OFERR`` and loses samples; ``inject_status`` adds
status bits (clock error, conversion error) from the next poll on. ``unsupported`` names
setters the device does not implement (they return ``AIO_ERR_SYS_NOT_SUPPORTED``, as
Contec documents for functions a device lacks); :meth:`unplug` / :meth:`replug` model a
USB glitch: every ID issued before it is invalid afterwards (``AIO_ERR_DLL_INVALID_ID``),
only a new ``AioInit`` works. Error numbers: Contec's, see ``ERRORS``.

Sequential conversion (``conversion_us`` per channel, 10 us as the AI-1608AY-USB's data
sheet gives): channel k of a scan is converted ``k x conversion_us`` after the scan's
clock edge, and a sampling clock shorter than ``channels x conversion_us`` cannot be
converted: ``AioStartAi`` succeeds, then the status shows ``AIS_SCERR`` and conversion
stops (Contec's API-AIO(WDM) help, glossary "Sampling clock period error": "when using 2
channels and internal clock 10 us is set for a device with conversion speed 10 usec/channel
... it is necessary to set an internal clock of at least 20 us"; "Conversion stops when
this error occurs").
"""

from __future__ import annotations

import ctypes

import numpy as np

AIS_BUSY, AIS_START_TRG, AIS_DATA_NUM = 0x1, 0x2, 0x10
AIS_OFERR, AIS_SCERR, AIS_AIERR, AIS_DRVERR = 0x10000, 0x20000, 0x40000, 0x80000

# Error numbers and texts: Contec's CAIO error codes as defined in Contec's own header
# ``libcpsaio.h`` (CONTEC CONPROSYS Linux driver, repository ``cps-driver``,
# ``include/libcpsaio.h``, "ERROR CODE" section; the same AIO_ERR_* numbering as the
# API-AIO(WDM) help's error list). Texts are our English renderings of the header's comments.
AIO_ERR_DLL_DEVICE_NAME = 10000    # device name not registered in the setting utility
AIO_ERR_DLL_INVALID_ID = 10001     # an invalid ID was specified
AIO_ERR_DLL_CALL_DRIVER = 10002    # the driver could not be called
AIO_ERR_AI_RANGE = 11060           # AiRange outside the function's range
AIO_ERR_SYS_NOT_SUPPORTED = 20001  # this function cannot be used with this device
AIO_ERR_SYS_BOARD_EXECUTING = 20002  # the device is running
AIO_ERR_AI_DEVICE_RANGE = 21060    # AiRange outside the device's ranges
AIO_ERR_AI_DEVICE_CHANNEL = 21420  # AiChannel outside the device's channels
AIO_ERR_PTR_AI_DATA_UNVERIFIED = 11421  # AIO_ERR_PTR_AI_DATA: closest header entry
AIO_ERR_SAMPLING_CLOCK_UNVERIFIED = 11300
"""NOT from a Contec header (none available to us lists the sampling-clock error): a
stand-in number for a sampling clock out of range; the driver treats it as any error."""

AIO_ERR_AI_TRIGGER_UNVERIFIED = 11140
"""NOT from a Contec header: a stand-in number for a trigger code outside those modelled."""
START_CODES = {"software": 0, "external rising": 1, "external falling": 2}
STOP_CODES = {"times": 0, "command": 4}

ERRORS = {
    AIO_ERR_DLL_DEVICE_NAME: "Device name not registered in the device manager",
    AIO_ERR_DLL_INVALID_ID: "Invalid ID",
    AIO_ERR_DLL_CALL_DRIVER: "Driver call failed",
    AIO_ERR_AI_RANGE: "AiRange is out of range of the function",
    AIO_ERR_SYS_NOT_SUPPORTED: "This function cannot be used with this device",
    AIO_ERR_SYS_BOARD_EXECUTING: "The device is running",
    AIO_ERR_AI_DEVICE_RANGE: "AiRange is out of range of the device",
    AIO_ERR_AI_DEVICE_CHANNEL: "AiChannel is out of range of the device",
    AIO_ERR_SAMPLING_CLOCK_UNVERIFIED: "Sampling clock out of range (stand-in number)",
}


def _target(arg):
    """The ctypes object an output argument refers to (byref / pointer / array)."""
    if isinstance(arg, ctypes.Array):
        return arg
    obj = getattr(arg, "_obj", None)  # byref() -> CArgObject
    if obj is not None:
        return obj
    if isinstance(arg, ctypes._Pointer):
        return arg.contents
    raise TypeError(f"not an output argument: {arg!r}")


class _Func:
    def __init__(self, name, impl, log):
        self.__name__ = name
        self._impl = impl
        self._log = log
        self.argtypes = None
        self.restype = ctypes.c_int

    def __call__(self, *args):
        if self.argtypes is None:
            raise RuntimeError(f"{self.__name__}: argtypes not declared (the driver must "
                               "declare prototypes as Contec's caio.py does)")
        if len(args) != len(self.argtypes):
            raise TypeError(f"{self.__name__}: this function takes {len(self.argtypes)} "
                            f"arguments ({len(args)} given)")
        for i, (a, t) in enumerate(zip(args, self.argtypes, strict=True)):
            try:
                t.from_param(a)
            except TypeError as exc:
                raise ctypes.ArgumentError(f"argument {i + 1}: {exc}") from None
        self._log.append((self.__name__, *[_plain(a) for a in args]))
        return self._impl(*args)


def _plain(a):
    if isinstance(a, (int, float, bytes)):
        return a
    if isinstance(a, (ctypes.c_short, ctypes.c_long, ctypes.c_float)):
        return a.value
    return type(a).__name__


def _val(a):
    return a.value if hasattr(a, "value") else a


class FakeCaioLibrary:
    """Fake CAIO with one AI-1608AY-USB named ``device_name``."""

    def __init__(self, bench, *, device_name="AIO000", max_channels=16, fifo_samples=4096,
                 wiring=None, range_V=10.0, resolution_bits=16, conversion_us=10.0):
        self.bench = bench
        self.device_name = device_name
        self.max_channels = max_channels
        self.fifo_samples = fifo_samples
        self.wiring = wiring or {}
        self.conversion_us = float(conversion_us)
        self.calls: list[tuple] = []
        self.plugged = True
        self.unsupported: set[str] = set()
        self._next_id = 0
        self.inject_status = 0
        self.range_V = range_V
        self.lsb_V = 2 * range_V / 2 ** resolution_bits
        self._ids: set[int] = set()
        self.channels = 1
        self.range_code = 0
        self.memory_type = self.clock_type = None
        self.clock_us = 1000.0
        self.start_trigger = 0
        self.stop_trigger = 4
        self.input_method = 0
        self.stop_times = 0
        self.running = False
        self._fifo = np.zeros((0, 1))
        self._t_first: float | None = None
        self._t_start_call = 0.0
        self._generated = 0
        self._status_err = 0
        for name in ("AioInit", "AioExit", "AioResetDevice", "AioGetErrorString",
                     "AioGetAiMaxChannels", "AioSetAiInputMethod", "AioSetAiChannels",
                     "AioSetAiRangeAll", "AioSetAiMemoryType", "AioSetAiClockType",
                     "AioSetAiSamplingClock", "AioGetAiSamplingClock", "AioSetAiStartTrigger",
                     "AioSetAiStopTrigger", "AioSetAiStopTimes", "AioResetAiMemory",
                     "AioStartAi", "AioStopAi", "AioGetAiStatus", "AioGetAiSamplingCount",
                     "AioGetAiSamplingDataEx"):
            setattr(self, name, _Func(name, getattr(self, "_" + name), self.calls))

    # -- helpers --------------------------------------------------------------------
    def _check_id(self, id_):
        if not self.plugged:
            # the USB device is gone: the driver behind the ID cannot be reached
            return AIO_ERR_DLL_CALL_DRIVER if _val(id_) in self._ids else AIO_ERR_DLL_INVALID_ID
        return 0 if _val(id_) in self._ids else AIO_ERR_DLL_INVALID_ID

    def unplug(self):
        """The USB cable is pulled: calls fail; IDs issued so far die with the device."""
        self.plugged = False
        self.running = False

    def replug(self):
        """The device is back; the old IDs stay invalid, ``AioInit`` gives a new one."""
        self._ids.clear()
        self.plugged = True

    def _advance(self):
        """Convert the samples that are due on the bench clock into the FIFO."""
        if not self.running:
            return
        now = self.bench.now()
        if self._t_first is None:
            if self.start_trigger == START_CODES["software"]:
                self._t_first = self._t_start_call
            elif self.start_trigger == START_CODES["external falling"]:
                return  # the fake bench's sync only rises at a trial's start
            else:
                t_trig = self.bench.trigger_time()
                if t_trig is None or t_trig < self._t_start_call:
                    return
                self._t_first = t_trig
        fs = 1e6 / self.clock_us
        if self.clock_us < self.channels * self.conversion_us * (1 - 1e-9):
            self._status_err |= AIS_SCERR  # "theoretically impossible to convert": stops
            self.running = False
            return
        due = int(np.floor((now - self._t_first) * fs)) + 1
        if self.stop_trigger == 0:
            due = min(due, self.stop_times)
        new = due - self._generated
        if new <= 0:
            return
        t = self._t_first + (self._generated + np.arange(new)) / fs
        force = self.bench.force_N(t, fs)
        scan = np.zeros((new, self.channels))
        for ch, fn in self.wiring.items():
            if ch < self.channels:  # converted one after the other within the scan
                scan[:, ch] = fn(t + ch * self.conversion_us * 1e-6, force)
        scan = np.clip(np.round(scan / self.lsb_V) * self.lsb_V, -self.range_V,
                       self.range_V - self.lsb_V)
        self._generated = due
        room = self.fifo_samples - len(self._fifo)
        if new > room:
            self._status_err |= AIS_OFERR
            scan = scan[:max(room, 0)]
        self._fifo = np.vstack([self._fifo, scan]) if len(self._fifo) else scan
        if self.stop_trigger == 0 and self._generated >= self.stop_times:
            self.running = False

    # -- common ---------------------------------------------------------------------
    def _AioInit(self, name, id_ptr):
        if not self.plugged or name.decode() != self.device_name:
            return AIO_ERR_DLL_DEVICE_NAME
        new_id = self._next_id  # never reissued: a stale ID cannot alias a new one
        self._next_id += 1
        self._ids.add(new_id)
        _target(id_ptr).value = new_id
        return 0

    def _AioExit(self, id_):
        err = self._check_id(id_)
        self._ids.discard(_val(id_))
        return err

    def _AioResetDevice(self, id_):
        err = self._check_id(id_)
        if not err:
            self.running = False
            self._fifo = np.zeros((0, self.channels))
            self._status_err = 0
        return err

    def _AioGetErrorString(self, code, buf):
        text = ERRORS.get(_val(code), "Unknown error").encode()
        ctypes.memmove(buf, text + b"\0", len(text) + 1)
        return 0

    # -- analog input -------------------------------------------------------------------
    def _ai_max(self) -> int:
        """Contec's help, AioGetAiMaxChannels: the number of channels "in the current input
        method"; differential input pairs two inputs per channel (half the single-ended)."""
        return self.max_channels // 2 if self.input_method == 1 else self.max_channels

    def _AioGetAiMaxChannels(self, id_, ptr):
        err = self._check_id(id_)
        if not err:
            _target(ptr).value = self._ai_max()
        return err

    def _AioSetAiInputMethod(self, id_, method):
        err = self._check_id(id_) or (0 if _val(method) in (0, 1) else AIO_ERR_AI_RANGE)
        if not err:
            self.input_method = _val(method)
        return err

    def _AioSetAiChannels(self, id_, n):
        err = self._check_id(id_)
        if err:
            return err
        if not 1 <= _val(n) <= self._ai_max():
            return AIO_ERR_AI_DEVICE_CHANNEL
        self.channels = _val(n)
        self._fifo = np.zeros((0, self.channels))
        return 0

    def _AioSetAiRangeAll(self, id_, code):
        err = self._check_id(id_)
        if err:
            return err
        if "AioSetAiRangeAll" in self.unsupported:
            return AIO_ERR_SYS_NOT_SUPPORTED
        if _val(code) != 0:
            return AIO_ERR_AI_DEVICE_RANGE  # the fake models the +/-10 V range only
        self.range_code = 0
        return 0

    def _AioSetAiMemoryType(self, id_, kind):
        err = self._check_id(id_)
        if err:
            return err
        if "AioSetAiMemoryType" in self.unsupported:
            return AIO_ERR_SYS_NOT_SUPPORTED
        self.memory_type = _val(kind)
        return 0

    def _AioSetAiClockType(self, id_, kind):
        self.clock_type = _val(kind)
        return self._check_id(id_)

    def _AioSetAiSamplingClock(self, id_, usec):
        err = self._check_id(id_)
        if err:
            return err
        if not 10.0 <= _val(usec) <= 1e6:
            return AIO_ERR_SAMPLING_CLOCK_UNVERIFIED
        self.clock_us = round(_val(usec) * 4) / 4  # 0.25 us clock granularity
        return 0

    def _AioGetAiSamplingClock(self, id_, ptr):
        err = self._check_id(id_)
        if not err:
            _target(ptr).value = self.clock_us
        return err

    def _AioSetAiStartTrigger(self, id_, trig):
        # caio.h / help AioSetAiStartTrigger: 0 software, 1 external trigger rising edge,
        # 2 falling edge (level and in/out-of-range triggers are not modelled: refused)
        err = self._check_id(id_)
        if err:
            return err
        if _val(trig) not in START_CODES.values():
            return AIO_ERR_AI_TRIGGER_UNVERIFIED
        self.start_trigger = _val(trig)
        return 0

    def _AioSetAiStopTrigger(self, id_, trig):
        # caio.h / help AioSetAiStopTrigger: 0 after the set number of samplings, 4 by
        # command (AioStopAi); the external and level stops are not modelled: refused
        err = self._check_id(id_)
        if err:
            return err
        if _val(trig) not in STOP_CODES.values():
            return AIO_ERR_AI_TRIGGER_UNVERIFIED
        self.stop_trigger = _val(trig)
        return 0

    def _AioSetAiStopTimes(self, id_, times):
        self.stop_times = _val(times)
        return self._check_id(id_)

    def _AioResetAiMemory(self, id_):
        self._fifo = np.zeros((0, self.channels))
        self._status_err = 0
        return self._check_id(id_)

    def _AioStartAi(self, id_):
        err = self._check_id(id_)
        if err:
            return err
        if self.running:
            return AIO_ERR_SYS_BOARD_EXECUTING
        self.running = True
        self._t_start_call = self.bench.now()
        self._t_first = None
        self._generated = 0
        return 0

    def _AioStopAi(self, id_):
        self._advance()
        self.running = False
        return self._check_id(id_)

    def _AioGetAiStatus(self, id_, ptr):
        err = self._check_id(id_)
        if err:
            return err
        self._advance()
        status = self._status_err | self.inject_status
        if self.running:
            status |= AIS_BUSY
            if self._t_first is None:
                status |= AIS_START_TRG
        _target(ptr).value = status
        return 0

    def _AioGetAiSamplingCount(self, id_, ptr):
        err = self._check_id(id_)
        if err:
            return err
        self._advance()
        _target(ptr).value = len(self._fifo)
        return 0

    def _AioGetAiSamplingDataEx(self, id_, n_ptr, data):
        err = self._check_id(id_)
        if err:
            return err
        n_obj = _target(n_ptr)
        n = min(n_obj.value, len(self._fifo))
        out = _target(data)
        if n * self.channels > len(out):
            return AIO_ERR_PTR_AI_DATA_UNVERIFIED
        flat = self._fifo[:n].ravel()  # interleaved: ch0, ch1, ... of scan 0, then scan 1
        out[:len(flat)] = flat.astype(np.float32).tolist()
        self._fifo = self._fifo[n:]
        n_obj.value = n
        return 0
