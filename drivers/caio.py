"""Contec AI-1608AY-USB through Contec's CAIO library (caio.dll / libcaio.so) via ctypes.

Prototypes, constants and the call sequence follow Contec's API-AIO headers and samples
(``caio.h`` "API-AIO(WDM) Definition File"; Contec's ``caio.py`` for Linux, whose ctypes
``argtypes`` this module copies; Contec's C / VB samples: ``AioSetAiMemoryType(Id, 0)``
FIFO, ``AioSetAiClockType(Id, 0)`` internal clock, ``AioSetAiSamplingClock(Id, usec)``,
``AioSetAiStartTrigger(Id, 0)`` software / ``(Id, 1)`` external trigger rising edge,
``AioSetAiStopTrigger(Id, 0)`` after ``AioSetAiStopTimes`` samples / ``(Id, 4)`` by
command, then ``AioResetAiMemory``, ``AioStartAi``, a polling loop on ``AioGetAiStatus`` /
``AioGetAiSamplingCount`` / ``AioGetAiSamplingDataEx``, ``AioStopAi``, ``AioExit``).

Acquisition: channels 0 .. n-1 are scanned (the sensor's analog force / moment outputs
and the stimulator's sync line, as the hardware config maps them), FIFO memory, internal
clock of 500 us (2000 Hz); with ``triggered=True`` conversion starts on the rising edge of
the stimulator's sync output wired to the external start-trigger input, so sample 0 is
stimulation onset. Reads are chunked by what :func:`AioGetAiSamplingCount` reports.

Status bits -> :class:`~nmsid.drivers.interfaces.AcquisitionFlags`: ``AIS_OFERR`` (FIFO
overflow, samples lost) and ``AIS_SCERR`` (sampling clock error: conversions missed)
-> ``overrun``; ``AIS_AIERR`` (A/D conversion error) and ``AIS_DRVERR`` -> ``sensor_fault``;
a sensor voltage at the edge of the range -> ``over_range``. A failed vendor call during a
read becomes ``sensor_fault`` (never an exception into the engine's loop).

Optional setters: ``AioSetAiRangeAll`` and ``AioSetAiMemoryType`` may not be implemented by
every device (the AI-1608AY-USB has one fixed +/-10 V range and a FIFO). When one answers
``AIO_ERR_SYS_NOT_SUPPORTED`` (20001, "this function cannot be used with this device",
Contec's ``libcpsaio.h``) the driver logs it and goes on with the device's fixed setting,
except for a configured range other than ``PM10``, which such a device cannot give (refused,
naming ``acquisition.caio.range``). Every other error of these calls is fatal.

Sampling clock vs channels: the device converts the scanned channels one after the other,
``conversion_us`` apart (the AI-1608AY-USB's data sheet: 10 us per channel), so a sampling
clock shorter than ``channels x conversion_us`` is "theoretically impossible to convert":
the device then sets ``AIS_SCERR`` and stops (Contec's API-AIO(WDM) help, glossary
"Sampling clock period error", whose example is 2 channels at 10 us/channel needing a
20 us clock). :meth:`CaioAcquisition.configure` refuses such a rate before starting, naming
the rate, the channels and the setting. The same sequential conversion delays channel k by
``k x conversion_us`` after the scan's start (:meth:`CaioAcquisition.sample_delay_s`; the
dry run corrects its onset figure for it). Both are inferred from that help page and the
data sheet, not measured on a device.

The dry run's monitor: with a calibration whose ``monitor_channel`` is set
(:func:`nmsid.drivers.hardware.with_monitor`), the chunk also carries that channel's volts
(``ForceChunk.monitor``), read in the same scan as force and sync.

USB glitch: :meth:`CaioAcquisition.reconnect` calls ``AioExit`` on the old ID (its failure
only logged), forgets it, and calls ``AioInit`` again for a NEW ID; no call is ever made
with a stale ID.
"""

from __future__ import annotations

import ctypes
import locale
import logging
import sys
import time
from ctypes import POINTER, c_char_p, c_float, c_long, c_short

import numpy as np

from nmsid.drivers.analog_force import AnalogSensor, NoLoadTare, convert_block, measure_no_load
from nmsid.drivers.errors import (
    DeviceError,
    DeviceNotFound,
    HardwareConfigError,
    VendorLibraryMissing,
)
from nmsid.drivers.interfaces import AcquisitionFlags, ForceChunk
from nmsid.protocols import os_platform

log = logging.getLogger(__name__)

# Status bits (caio.h, "Analog Input Status")
AIS_BUSY = 0x00000001
AIS_START_TRG = 0x00000002
AIS_DATA_NUM = 0x00000010
AIS_OFERR = 0x00010000
AIS_SCERR = 0x00020000
AIS_AIERR = 0x00040000
AIS_DRVERR = 0x00080000

RANGES_V = {"PM10": (0, 10.0), "PM5": (1, 5.0), "PM25": (2, 2.5), "PM125": (3, 1.25),
            "PM1": (4, 1.0)}
"""Bipolar input ranges (caio.h ``PM10`` = 0 ...): name -> (code, +/- volts)."""
INPUT_METHODS = {"single_ended": 0, "differential": 1}
MEMORY_FIFO = 0
CLOCK_INTERNAL = 0
START_SOFTWARE = 0
START_EXTERNAL_RISING = 1
STOP_AFTER_TIMES = 0
STOP_BY_COMMAND = 4

AIO_ERR_SYS_NOT_SUPPORTED = 20001
"""Contec's error number for "this function cannot be used with this device" (``AIO_ERR_
SYS_NOT_SUPPORTED`` in ``libcpsaio.h`` of Contec's CONPROSYS Linux driver)."""

_PROTOTYPES = {
    "AioInit": [c_char_p, POINTER(c_short)],
    "AioExit": [c_short],
    "AioResetDevice": [c_short],
    "AioGetErrorString": [c_long, c_char_p],
    "AioGetAiMaxChannels": [c_short, POINTER(c_short)],
    "AioSetAiInputMethod": [c_short, c_short],
    "AioSetAiChannels": [c_short, c_short],
    "AioSetAiRangeAll": [c_short, c_short],
    "AioSetAiMemoryType": [c_short, c_short],
    "AioSetAiClockType": [c_short, c_short],
    "AioSetAiSamplingClock": [c_short, c_float],
    "AioGetAiSamplingClock": [c_short, POINTER(c_float)],
    "AioSetAiStartTrigger": [c_short, c_short],
    "AioSetAiStopTrigger": [c_short, c_short],
    "AioSetAiStopTimes": [c_short, c_long],
    "AioResetAiMemory": [c_short],
    "AioStartAi": [c_short],
    "AioStopAi": [c_short],
    "AioGetAiStatus": [c_short, POINTER(c_long)],
    "AioGetAiSamplingCount": [c_short, POINTER(c_long)],
    "AioGetAiSamplingDataEx": [c_short, POINTER(c_long), POINTER(c_float)],
}


def load_caio(path: str = "") -> object:
    """Load caio.dll (Windows) or libcaio.so (Linux) and declare the prototypes used.

    Raises
    ------
    VendorLibraryMissing
        If the library cannot be loaded (one line saying how to install it).
    """
    name = path or ("caio.dll" if sys.platform.startswith("win") else "libcaio.so")
    try:
        if sys.platform == "win32":  # the real OS decides which loader (not the switch)
            lib = ctypes.WinDLL(name)
        else:
            lib = ctypes.CDLL(name)
    except OSError:
        raise VendorLibraryMissing(
            f"the Contec CAIO library ({name})", "the Contec AI-1608AY-USB",
            "install Contec's API-AIO(WDM) (Windows) or API-AIO(LNX) (Linux) driver, or "
            "set acquisition.caio.library to its path") from None
    return declare(lib)


def declare(lib) -> object:
    """Set ``argtypes`` / ``restype`` of every function used (as Contec's caio.py does)."""
    for func, argtypes in _PROTOTYPES.items():
        f = getattr(lib, func)
        f.argtypes = argtypes
        f.restype = c_long
    return lib


def encode_device_name(name: str) -> bytes:
    """The device name as ``AioInit``'s ``char*`` wants it.

    Contec's setting utility lets a lab name the device freely (``AIO000`` by default);
    ``AioInit`` is an ANSI (``char*``) function, which on Windows takes the system's ANSI
    code page (Microsoft, "Unicode in the Windows API": the "A" functions use the current
    Windows code page; Python's ``mbcs`` codec), elsewhere the locale's encoding.

    Raises
    ------
    HardwareConfigError
        A name the code page cannot represent (one line naming it).
    """
    codec = "mbcs" if os_platform.is_windows() else locale.getpreferredencoding(False)
    try:
        return name.encode(codec)
    except LookupError:  # the mbcs codec exists only on Windows itself
        return name.encode("utf-8")
    except UnicodeEncodeError:
        raise HardwareConfigError(
            f"acquisition.caio.device_name = {name!r} cannot be passed to AioInit in this "
            f"system's code page ({codec}); rename the device in Contec's device manager to "
            "plain letters and digits (e.g. AIO000)") from None


class CaioAcquisition:
    """:class:`~nmsid.drivers.interfaces.ForceAcquisition` over a Contec AI-1608AY-USB.

    Parameters
    ----------
    calibration : AnalogCalibration or DynamometerCalibration
        Channel map and volts-to-newtons calibration.
    device_name : str
        The CAIO device name set in Contec's device manager (e.g. ``AIO000``).
    ai_range : str
        Input range name (``PM10`` = +/-10 V, ...).
    input_method : str
        ``single_ended``, ``differential`` or empty (leave the device's setting).
    library : str
        Path of caio.dll / libcaio.so; empty for the system's.
    lib : object, optional
        An already loaded library (tests pass the fake here).
    max_chunk : int
        Most samples (per channel) fetched per read.
    poll_s : float
        Status polling interval while waiting for samples.
    conversion_us : float
        Conversion time per scanned channel (us); the AI-1608AY-USB's data sheet says 10.
    """

    def __init__(self, calibration: AnalogSensor, *, device_name: str = "AIO000",
                 ai_range: str = "PM10", input_method: str = "", library: str = "",
                 lib=None, max_chunk: int = 4000, poll_s: float = 0.005,
                 conversion_us: float = 10.0):
        if ai_range not in RANGES_V:
            raise HardwareConfigError(f"acquisition.caio.range {ai_range!r} is not one of "
                             f"{sorted(RANGES_V)}")
        if input_method and input_method not in INPUT_METHODS:
            raise HardwareConfigError(f"acquisition.caio.input_method {input_method!r} is not "
                                      f"one of {sorted(INPUT_METHODS)} (or empty)")
        self.cal = calibration
        for warning in calibration.implausible():
            log.warning("%s", warning)
        self.device_name = device_name
        self.range_code, self.range_V = RANGES_V[ai_range]
        self.input_method = input_method
        self.library = library
        self._lib = lib
        self.max_chunk = max_chunk
        self.poll_s = poll_s
        self.conversion_us = float(conversion_us)
        self._id = c_short(-1)
        self._open = False
        self._fs_Hz = 0.0
        self._running = False
        self._index = 0
        self._remaining: int | None = None
        self._buf: ctypes.Array[c_float] | None = None
        self._fault = ""
        self.max_channels = 0
        self.ai_range = ai_range
        self.unsupported: list[str] = []
        """Optional setters the device answered with AIO_ERR_SYS_NOT_SUPPORTED."""
        self._tare = NoLoadTare()
        """No-load voltages, measured before a session's first block and after each rest
        (CFS manual 4.2; :mod:`nmsid.drivers.analog_force`)."""
        self._capture: list[np.ndarray] | None = None

    @property
    def fs_Hz(self) -> float:
        return self._fs_Hz

    # -- vendor calls -----------------------------------------------------------------
    @property
    def lib(self):
        if self._lib is None:
            self._lib = load_caio(self.library)
        return self._lib

    def _error_text(self, code: int) -> str:
        buf = ctypes.create_string_buffer(256)
        try:
            self.lib.AioGetErrorString(c_long(code), buf)
            return buf.value.decode("ascii", errors="replace") or "no description"
        except Exception:
            return "no description"

    def _call(self, func: str, *args) -> None:
        ret = getattr(self.lib, func)(*args)
        if ret != 0:
            raise DeviceError(f"{func} on Contec {self.device_name!r} failed with error "
                              f"{ret}: {self._error_text(ret)}")

    def _call_optional(self, func: str, *args, fixed: str) -> None:
        """Like :meth:`_call`, but "not supported by this device" is logged and tolerated.

        ``fixed`` says what the device then uses (for the log).
        """
        ret = getattr(self.lib, func)(*args)
        if ret == 0:
            return
        if ret == AIO_ERR_SYS_NOT_SUPPORTED:
            self.unsupported.append(func)
            log.warning("Contec %s does not support %s (error %d: %s); its fixed setting is "
                        "used: %s", self.device_name, func, ret, self._error_text(ret), fixed)
            return
        raise DeviceError(f"{func} on Contec {self.device_name!r} failed with error "
                          f"{ret}: {self._error_text(ret)}")

    # -- lifecycle ------------------------------------------------------------------
    def open(self) -> None:
        if self._open:
            return
        ret = self.lib.AioInit(encode_device_name(self.device_name), ctypes.byref(self._id))
        if ret != 0:
            raise DeviceNotFound(f"Contec device {self.device_name!r} not found (AioInit "
                                 f"error {ret}: {self._error_text(ret)}); check the device "
                                 "name in Contec's device manager and "
                                 "acquisition.caio.device_name")
        self._open = True
        try:
            self._call("AioResetDevice", self._id)
            if self.input_method:
                self._call("AioSetAiInputMethod", self._id,
                           c_short(INPUT_METHODS[self.input_method]))
            # after the input method: Contec's help, AioGetAiMaxChannels gives the channels
            # of the CURRENT input method (differential pairs inputs: half of them)
            maxch = c_short(0)
            self._call("AioGetAiMaxChannels", self._id, ctypes.byref(maxch))
            self.max_channels = maxch.value
            if self.cal.n_channels > self.max_channels:
                raise DeviceError(f"the channel map needs {self.cal.n_channels} channels, "
                                  f"{self.device_name!r} has {self.max_channels}"
                                  + (f" in {self.input_method} input" if self.input_method
                                     else ""))
            self._call("AioSetAiChannels", self._id, c_short(self.cal.n_channels))
            self.unsupported = []
            self._call_optional("AioSetAiRangeAll", self._id, c_short(self.range_code),
                                fixed="+/-10 V (the AI-1608AY-USB's only range)")
            if "AioSetAiRangeAll" in self.unsupported and self.ai_range != "PM10":
                raise DeviceError(
                    f"Contec {self.device_name!r} cannot set its input range, so "
                    f"acquisition.caio.range = {self.ai_range!r} cannot be used; set it to "
                    "'PM10' (the device's fixed +/-10 V)")
            self._call_optional("AioSetAiMemoryType", self._id, c_short(MEMORY_FIFO),
                                fixed="FIFO")
            self._call("AioSetAiClockType", self._id, c_short(CLOCK_INTERNAL))
        except Exception:
            self.close()
            raise

    def configure(self, fs_Hz: float) -> float:
        """Set the sampling clock to ``1e6 / fs_Hz`` us; return the rate the device uses."""
        if not fs_Hz > 0:
            raise HardwareConfigError(f"acquisition.fs_Hz must be > 0, got {fs_Hz!r}")
        n = self.cal.n_channels
        if 1e6 / fs_Hz < n * self.conversion_us * (1 - 1e-9):
            raise HardwareConfigError(
                f"Contec {self.device_name!r}: {fs_Hz:g} Hz over {n} scanned channels (0 .. "
                f"{n - 1}) needs {fs_Hz * n / 1000:g} kS/s, but at "
                f"{self.conversion_us:g} us per channel (acquisition.caio.conversion_us) the "
                f"device converts at most {1e3 / self.conversion_us:g} kS/s, i.e. "
                f"{1e6 / (n * self.conversion_us):g} Hz for {n} channels; wire the channels to "
                "lower inputs or lower the rate")
        self.open()
        self._call("AioSetAiSamplingClock", self._id, c_float(1e6 / fs_Hz))
        actual = c_float(0.0)
        self._call("AioGetAiSamplingClock", self._id, ctypes.byref(actual))
        self._fs_Hz = 1e6 / actual.value if actual.value > 0 else fs_Hz
        return self._fs_Hz

    def start(self, n_samples: int | None = None, *, triggered: bool = True) -> None:
        """The trial's block; first the no-load voltages, when due (the tare)."""
        if not self._fs_Hz:
            raise DeviceError("configure(fs_Hz) must be called before start()")
        measure_no_load(self, f"Contec {self.device_name!r}")
        self._start_block(n_samples, triggered=triggered)

    def _start_block(self, n_samples: int | None, *, triggered: bool) -> None:
        self._call("AioSetAiStartTrigger", self._id,
                   c_short(START_EXTERNAL_RISING if triggered else START_SOFTWARE))
        if n_samples is None:
            self._call("AioSetAiStopTrigger", self._id, c_short(STOP_BY_COMMAND))
        else:
            self._call("AioSetAiStopTrigger", self._id, c_short(STOP_AFTER_TIMES))
            self._call("AioSetAiStopTimes", self._id, c_long(int(n_samples)))
        self._call("AioResetAiMemory", self._id)
        self._index = 0
        self._remaining = n_samples
        self._fault = ""
        self._buf = (c_float * (self.max_chunk * self.cal.n_channels))()
        self._call("AioStartAi", self._id)
        self._running = True

    def read(self, timeout_s: float) -> ForceChunk | None:
        if not self._running:
            return None
        deadline = time.monotonic() + timeout_s
        while True:
            status, count = c_long(0), c_long(0)
            try:
                self._call("AioGetAiStatus", self._id, ctypes.byref(status))
                self._call("AioGetAiSamplingCount", self._id, ctypes.byref(count))
                flags = self._flags(status.value)
                if count.value > 0:
                    n = c_long(min(count.value, self.max_chunk))
                    self._call("AioGetAiSamplingDataEx", self._id, ctypes.byref(n), self._buf)
                    return self._chunk(n.value, flags)
            except DeviceError as exc:
                self._fault = str(exc)
                log.error("%s", exc)
                return self._empty(AcquisitionFlags(sensor_fault=True, detail=self._fault))
            if flags.any:
                return self._empty(flags)
            if not status.value & AIS_BUSY:
                return None  # finished (or stopped) and drained
            now = time.monotonic()
            if now >= deadline:
                return None
            time.sleep(min(self.poll_s, deadline - now))

    def _flags(self, status: int) -> AcquisitionFlags:
        details = []
        if status & AIS_OFERR:
            details.append("FIFO overflow (AIS_OFERR): samples lost")
        if status & AIS_SCERR:
            details.append("sampling clock error (AIS_SCERR): conversions missed")
        if status & AIS_AIERR:
            details.append("A/D conversion error (AIS_AIERR)")
        if status & AIS_DRVERR:
            details.append("driver error (AIS_DRVERR)")
        return AcquisitionFlags(overrun=bool(status & (AIS_OFERR | AIS_SCERR)),
                                sensor_fault=bool(status & (AIS_AIERR | AIS_DRVERR)),
                                detail="; ".join(details))

    def _chunk(self, n: int, flags: AcquisitionFlags) -> ForceChunk:
        volts = np.ctypeslib.as_array(self._buf)[:n * self.cal.n_channels].astype(np.float64)
        volts = volts.reshape(n, self.cal.n_channels)
        if self._capture is not None:
            self._capture.append(volts)
        block = convert_block(volts, self.cal, self.range_V, tare_wrench=self._tare.wrench)
        if block.saturated:
            flags = AcquisitionFlags(overrun=flags.overrun, over_range=True,
                                     sensor_fault=flags.sensor_fault,
                                     detail="; ".join(filter(None, [flags.detail,
                                         f"sensor output at the edge of +/-{self.range_V:g} V"])))
        chunk = ForceChunk(start_index=self._index, force_N=block.force_N,
                           wrench=block.wrench, sync=block.sync_V, flags=flags,
                           monitor=block.monitor_V)
        self._index += n
        if self._remaining is not None:
            self._remaining = max(0, self._remaining - n)
        return chunk

    def _empty(self, flags: AcquisitionFlags) -> ForceChunk:
        return ForceChunk(start_index=self._index, force_N=np.zeros(0),
                          wrench=np.zeros((0, 6)) if self.cal.full_wrench else None,
                          sync=np.zeros(0) if self.cal.sync_channel is not None else None,
                          flags=flags,
                          monitor=np.zeros(0) if self.cal.monitor_channel is not None else None)

    def sample_delay_s(self, channel: int) -> float:
        """How long after the scan's start channel ``channel`` is converted (sequential
        conversion, ``conversion_us`` per channel; see the module docstring)."""
        return channel * self.conversion_us * 1e-6

    def stop(self) -> None:
        if self._running:
            self._tare.stopped()
        self._stop_block()

    def _stop_block(self) -> None:
        if self._running and self._open:
            self._running = False
            try:
                self._call("AioStopAi", self._id)
            except DeviceError as exc:
                log.warning("%s", exc)

    def close(self) -> None:
        try:
            self.stop()
        finally:
            if self._open:
                self._open = False
                try:
                    self._call("AioExit", self._id)
                except DeviceError as exc:
                    log.warning("%s", exc)
                self._id = c_short(-1)  # never used again: AioInit issues a new one
                self._fs_Hz = 0.0

    def device_fault(self) -> str:
        """Between trials: "" if the device answers ``AioGetAiStatus``, else the error."""
        if not self._open:
            return f"Contec {self.device_name!r} is not open"
        status = c_long(0)
        try:
            self._call("AioGetAiStatus", self._id, ctypes.byref(status))
        except DeviceError as exc:
            return str(exc)
        return ""

    def reconnect(self, fs_Hz: float) -> float:
        """After a USB glitch: release the old ID, ``AioInit`` anew, set everything again.

        Returns
        -------
        float
            The sampling rate the device uses.

        Raises
        ------
        DeviceNotFound
            If the device is still not there (``AioInit`` fails).
        """
        self._running = False
        self.close()
        self._tare.forget()
        return self.configure(fs_Hz)

    def describe(self) -> dict:
        return {"device": self.device_name, "max_channels": self.max_channels,
                "scanned_channels": self.cal.n_channels, "range_V": self.range_V,
                "fs_Hz": self._fs_Hz}

