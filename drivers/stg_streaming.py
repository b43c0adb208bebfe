"""The MCS STG4002 in STREAMING mode: stimulation updated while it runs (closed loop).

:class:`StgStreamingStimulator` implements
:class:`~nmsid.drivers.interfaces.HostStreamedStimulator` over McsUsbNet's
``CStg200xStreamingNet`` (issue 28, item 1). Vendor sources, cited beside each behaviour:
the McsUsbNet manual, section 6.3 "Streaming mode" (``McsUsbNet.pdf`` in
``shared/vendor/McsUsbNet-5.3.15/``), and the XML documentation of the same release. Every
member called is declared in :mod:`nmsid.drivers.mcs_surface` and held to the real
assembly there.

One update = one carrier period. :meth:`~StgStreamingStimulator.open_stream` fixes the
ceilings and the carrier (``update_Hz``; a whole number ``P`` of output samples per period
at the output rate, "maximum of 50 kHz", manual 6.3). :meth:`~StgStreamingStimulator.write_stream`
takes one amplitude per channel per update, refuses any above its ceiling before anything
reaches the device (:class:`~nmsid.drivers.interfaces.CurrentLimitError`, nothing
enqueued), renders each period as a charge-balanced sine (:func:`render_periods`) and
enqueues it with ``EnqueueData``.

Charge balance after the device's truncation: "The values for the analog outputs are 16
bits signed integers. The lower bits are truncated according to the resolution of the
STG" (manual 6.3). Every value sent is a multiple of :func:`quantum` Int16 steps (the
smallest power of two at or above the device's resolution), so truncating the lower bits
changes nothing; the second half-wave is the exact negative mirror of the first and the
first sample of a period is 0, so every period sums to exactly zero as played.

Underrun: ``DisableContinousMode`` -- "the STG stops when it runs out of data. It has to be
retriggered" (manual 6.3); an underrun therefore ends the output instead of holding a
value. The driver sees it in the PC queue: a running STG drains the queue at the output
rate (less at most its own ring's latency), so a queue drained by less than that means the
device has stopped, and the next :meth:`~StgStreamingStimulator.write_stream` raises
:class:`StreamUnderrunError` naming how far the host fell behind (the interlock trips; the
output is already at zero). After the host's last write no write can notice: an STG that
ran dry then (data that never reached its memory, or a last write a little too late) is
found by :meth:`~StgStreamingStimulator.close_stream`, which counts what played (written,
less what ``GetDataQueueSpace`` and ``GetFramesBuffered`` still hold) and returns the
underrun's line, when the STG stopped and how much was not delivered (``run_block`` aborts
the trial with it). Stop: :meth:`~StgStreamingStimulator.stop_now` is the immediate
``SendStop`` and ``StopLoop``; a failed ``SendStop`` tells the operator to switch the STG off, as in
download mode.

Priming: ``StartLoop`` only begins moving the PC queue into the STG's memory (the manual's
6.3 example waits: "Give StartLoop some time"), and an STG started with nothing in its
memory runs dry at once and stops (continuous mode disabled, above).
:meth:`~StgStreamingStimulator.start` therefore sends ``SendStart`` only once ``GetFramesBuffered``
(XML: "the number of frames currently buffered in STG Memory") shows the queued updates there, or as
many as the STG's ring holds; if they do not arrive within :data:`PRIME_TIMEOUT_S` nothing starts
(DeviceError).

Latency: the STG keeps its ring buffer "about half full", so "latency = (ringbuffersize in
bytes/4) / output rate" (manual 6.3); :attr:`~StgStreamingStimulator.latency_s` reports it
for the ring size set with ``SetCapacity``.

Not verified on hardware: written against ``testing/fakes/fake_stg_streaming.py`` (built
from the same documents) only.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable

import numpy as np

from nmsid.drivers.errors import DeviceError, DeviceRangeError, StimulatorSettingError
from nmsid.drivers.interfaces import (
    CurrentLimitError,
    StimulatorCapabilities,
    StimulatorState,
    StimulatorStatus,
)
from nmsid.drivers.mcs_usb import DEFAULT_DLL, find_stg, load_mcs_usb
from nmsid.drivers.stg4002 import Stg4002Stimulator
from nmsid.drivers.stg_waveform import NA_PER_MA
from nmsid.errors import SafetyError

log = logging.getLogger(__name__)

INT16_FULL = 32768
"""Int16 steps per full range (manual 6.3 example: ``(2^(16-1) - 1) * sin``)."""
RING_S = 2.5
"""Default PC ring buffer, in seconds of output: room for the deepest queue a controller
design allows (20 updates at 10 Hz = 2 s) and the update being written."""
UNDERRUN_SLACK_S = 0.02
"""Allowance on the drain test for USB transfers and clock reads (20 ms: one update at
50 Hz)."""
CLOSE_BACKSTOP_S = 2.0
"""Real seconds :meth:`StgStreamingStimulator.close_stream` waits beyond ten times what is
left to play, should the driver's clock not move (a fake bench's clock always moves)."""
PRIME_TIMEOUT_S = 1.0
"""How long :meth:`StgStreamingStimulator.start` waits for the queued data to reach the
STG's memory (``GetFramesBuffered``) before ``SendStart``; generous (a loaded host)."""
BYTES_PER_FRAME = 4
"""The STG ring's frames: ``SetCapacity`` bytes / 4, as the manual's latency formula
(6.3: "ringbuffersize in bytes/4") counts them (ASSUMED; a first-day bench check)."""
CALLBACK_THRESHOLD_PCT = 50
"""``SetupTrigger`` callback_threshold: "in percent of the buffer level" (XML; the manual's
example uses 50)."""


def quantum(range_nA: float, resolution_nA: float) -> int:
    """Int16 steps per value step: the smallest power of two at or above the device's
    resolution, so that the device's truncation of the lower bits is a no-op."""
    lsb_nA = range_nA / INT16_FULL
    steps = max(resolution_nA / lsb_nA, 1.0)
    return 1 << max(0, math.ceil(math.log2(steps) - 1e-12))


def render_periods(amplitudes_mA: np.ndarray, P: int, range_nA: float, q: int) -> np.ndarray:
    """One charge-balanced sine period of ``P`` samples per amplitude, as Int16 values.

    ``v[0] = 0``; ``v[j]`` for ``1 <= j < P/2`` is ``A sin(2 pi j / P)`` in Int16 steps,
    quantised TOWARD ZERO to a multiple of ``q`` (never above the amplitude, hence never
    above the ceiling); ``v[P - j] = -v[j]`` and ``v[P/2] = 0`` for even ``P``. Every period
    sums to exactly zero.
    """
    a = np.asarray(amplitudes_mA, dtype=float)
    j = np.arange(1, (P + 1) // 2)
    half = np.sin(2 * np.pi * j / P)[None, :] * (a[:, None] * NA_PER_MA / range_nA
                                                 * (INT16_FULL - 1))
    half = np.trunc(half / q) * q
    out = np.zeros((len(a), P), dtype=np.int64)
    out[:, j] = half
    out[:, P - j] = -half
    return out.reshape(-1).astype(np.int16)


class StreamUnderrunError(DeviceError):
    """The STG ran out of streamed data and stopped (manual 6.3): the host fell behind."""


class StgStreamingStimulator:
    """An STG4002 in streaming mode (see the module docstring).

    Parameters
    ----------
    ceiling_ext_mA, ceiling_flex_mA : float
        The rig's hard ceilings; a stream's own ceilings must be at or below them.
    extensor_channel, flexor_channel, sync_out : int
        Outputs numbered from 1.
    serial, dll_path : str
    output_rate_Hz : float
        ``SetOutputRate`` (streaming mode only; "maximum of 50 kHz").
    ring_samples : int, optional
        PC ring buffer per channel (the constructor's ``ringbuffer_size``); default
        :data:`RING_S` seconds at the output rate.
    stg_ring_bytes : int
        STG-side ring buffer of trigger 1 (``SetCapacity``); sets the latency.
    api : namespace, optional
        Loaded vendor names (tests); default :func:`load_mcs_usb` plus the streaming class.
    clock : callable, optional
        Seconds on the device's time base for the underrun test (default
        ``time.monotonic``; a fake bench passes its own clock).
    """

    def __init__(self, *, ceiling_ext_mA: float, ceiling_flex_mA: float,
                 extensor_channel: int = 1, flexor_channel: int = 2, sync_out: int = 1,
                 serial: str = "", dll_path: str = DEFAULT_DLL,
                 output_rate_Hz: float = 50_000.0, ring_samples: int | None = None,
                 stg_ring_bytes: int = 16_000, api=None,
                 clock: Callable[[], float] | None = None):
        if extensor_channel == flexor_channel:
            raise StimulatorSettingError("extensor_channel and flexor_channel must differ")
        if not 1000 <= output_rate_Hz <= 50_000:
            raise StimulatorSettingError(f"streaming output rate {output_rate_Hz:g} Hz is "
                                         "outside 1000 .. 50000 Hz (McsUsbNet SetOutputRate)")
        self.rig_ceiling_mA = {extensor_channel: float(ceiling_ext_mA),
                               flexor_channel: float(ceiling_flex_mA)}
        self.ext_ch, self.flex_ch, self.sync_out = extensor_channel, flexor_channel, sync_out
        self.serial, self.dll_path = serial, dll_path
        self.output_rate_Hz = float(output_rate_Hz)
        self.ring_samples = int(round(RING_S * self.output_rate_Hz) if ring_samples is None
                                else ring_samples)
        self._now = clock or time.monotonic
        self._t_start: float | None = None
        self._enqueued = 0          # samples per channel enqueued since open_stream
        self.stg_ring_bytes = int(stg_ring_bytes)
        self._api = api
        self._dev = None
        self._io = threading.Lock()
        self._state = StimulatorState.DISCONNECTED
        self._range_nA: dict[int, float] = {}
        self._res_nA: dict[int, float] = {}
        self._caps: StimulatorCapabilities | None = None
        self._stream_ceiling: dict[int, float] = {}
        self._P = 0
        self._K = 1
        self._q = 1
        self._started = False
        self._error = ""
        self._stop_error = ""
        self._close_underrun = ""
        self.enqueued_periods = 0

    # -- vendor ---------------------------------------------------------------------------
    @property
    def api(self):
        if self._api is None:
            self._api = load_mcs_usb(self.dll_path)
            from Mcs.Usb import CStg200xStreamingNet  # noqa: PLC0415 (pythonnet)
            from System import Int16, UInt16  # noqa: PLC0415
            self._api.CStg200xStreamingNet = CStg200xStreamingNet
            self._api.Int16, self._api.UInt16 = Int16, UInt16
        return self._api

    def _u32(self, v: int):
        return self.api.UInt32(int(v))

    def connect(self) -> None:
        """Open the streaming handle and read the device (no output)."""
        if self._dev is not None:
            self.disconnect()
        api = self.api
        entry = find_stg(api, self.serial)
        # constructor (UInt32 ringbuffer_size): "the size of the ringbuffer in PC memory"
        dev = api.CStg200xStreamingNet(self._u32(self.ring_samples))
        status = dev.Connect(entry)
        if status not in (None, 0):
            raise DeviceError(f"McsUsbNet Connect (streaming) to STG {entry.SerialNumber} "
                              f"failed with status {status}")
        self._dev = dev
        n_ch = int(dev.GetNumberOfAnalogChannels())
        for ch in (self.ext_ch, self.flex_ch):
            if not 1 <= ch <= n_ch:
                raise StimulatorSettingError(f"stimulator channel {ch} does not exist "
                                             f"({n_ch} channels)")
        if not 1 <= self.sync_out <= int(dev.GetNumberOfSyncoutChannels()):
            raise StimulatorSettingError(f"stimulator.sync_out = {self.sync_out} does not "
                                         "exist")
        dev.SetCurrentMode()
        for ch in (self.ext_ch, self.flex_ch):
            self._range_nA[ch] = float(dev.GetCurrentRangeInNanoAmp(self._u32(ch - 1)))
            self._res_nA[ch] = float(dev.GetCurrentResolutionInNanoAmp(self._u32(ch - 1)))
            if self.rig_ceiling_mA[ch] > self._range_nA[ch] / NA_PER_MA:
                raise DeviceRangeError(f"current ceiling {self.rig_ceiling_mA[ch]:g} mA on "
                                       f"channel {ch} exceeds the device's range")
        self._caps = StimulatorCapabilities(
            n_channels=n_ch, max_current_mA=min(self._range_nA.values()) / NA_PER_MA,
            resolution_mA=max(self._res_nA.values()) / NA_PER_MA,
            output_rate_Hz=self.output_rate_Hz, model=str(entry.DeviceName),
            serial=str(entry.SerialNumber))
        self._state = StimulatorState.IDLE

    def capabilities(self) -> StimulatorCapabilities:
        if self._caps is None:
            raise DeviceError("the STG is not connected; call connect() first")
        return self._caps

    # -- the stream ----------------------------------------------------------------------
    def open_stream(self, ceiling_ext_mA: float, ceiling_flex_mA: float,
                    update_Hz: float, carrier_Hz: float | None = None) -> float:
        """Configure streaming: ceilings, carrier, output rate, STG ring buffer, trigger 1
        with the two channels and the sync; ``StartLoop``. Nothing plays before
        :meth:`start` (``SendStart``), so the acquisition can be armed on the sync first.

        Parameters
        ----------
        ceiling_ext_mA, ceiling_flex_mA : float
            The stream's ceilings, at or below the rig's.
        update_Hz : float
            Amplitude updates per second (the controller's rate).
        carrier_Hz : float, optional
            The protocol's carrier; default ``update_Hz`` (one period per update). Each
            update lasts ``carrier_Hz / update_Hz`` whole carrier periods, each period a
            whole number ``P`` (>= 4) of output samples, so the amplitude is constant over
            every charge-balanced period.

        Returns
        -------
        float
            ``update_Hz`` exactly (a rate that does not fit is refused, never rounded).

        Raises
        ------
        DeviceRangeError
            A ceiling above the rig's.
        StimulatorSettingError
            A carrier that does not divide the output rate, or an update rate that does
            not divide the carrier (one line naming the rates).
        """
        if self._dev is None:
            self.connect()
        for ch, c in ((self.ext_ch, ceiling_ext_mA), (self.flex_ch, ceiling_flex_mA)):
            if not 0 <= c <= self.rig_ceiling_mA[ch]:
                raise DeviceRangeError(f"stream ceiling {c:g} mA on channel {ch} exceeds the "
                                       f"rig ceiling {self.rig_ceiling_mA[ch]:g} mA")
        carrier = float(update_Hz if carrier_Hz is None else carrier_Hz)
        P = round(self.output_rate_Hz / carrier)
        if P < 4 or abs(self.output_rate_Hz / P - carrier) > 1e-9 * carrier:
            raise StimulatorSettingError(
                f"carrier {carrier:g} Hz must divide the STG's streaming output rate "
                f"{self.output_rate_Hz:g} Hz into a whole number (>= 4) of samples")
        K = round(carrier / update_Hz)
        if K < 1 or abs(carrier / K - update_Hz) > 1e-9 * update_Hz:
            raise StimulatorSettingError(
                f"update rate {update_Hz:g} Hz must divide the carrier {carrier:g} Hz into a "
                "whole number of periods per update (design the controller with "
                "--update-hz at such a rate)")
        self._stream_ceiling = {self.ext_ch: float(ceiling_ext_mA),
                                self.flex_ch: float(ceiling_flex_mA)}
        self._P, self._K = P, K
        self._q = max(quantum(self._range_nA[ch], self._res_nA[ch])
                      for ch in (self.ext_ch, self.flex_ch))
        api, dev = self.api, self._dev
        if dev is None:
            raise DeviceError("the STG did not connect")
        with self._io:
            dev.SetOutputRate(self._u32(int(self.output_rate_Hz)))   # manual 6.3
            dev.DisableContinousMode()                               # manual 6.3: stop on empty
            n_trig = int(dev.GetNumberOfTriggerInputs())
            total = int(dev.GetTotalMemory())
            cap = [0] * n_trig
            cap[0] = min(self.stg_ring_bytes, total)                 # manual 6.3: SetCapacity
            dev.SetCapacity(api.Array[api.UInt32](cap))
            channelmap, syncmap, digout, autostart, threshold = ([0] * n_trig for _ in range(5))
            channelmap[0] = (1 << (self.ext_ch - 1)) | (1 << (self.flex_ch - 1))
            syncmap[0] = 1 << (self.sync_out - 1)
            threshold[0] = CALLBACK_THRESHOLD_PCT
            dev.SetupTrigger(*(api.Array[api.UInt32](a) for a in
                               (channelmap, syncmap, digout, autostart, threshold)))
            dev.StartLoop()
        self._started = False
        self._t_start = None
        self._enqueued = 0
        self._close_underrun = ""
        self._state = StimulatorState.ARMED
        return float(update_Hz)

    @property
    def samples_per_update(self) -> int:
        """Output samples per update of the open stream (``P`` x periods per update)."""
        return self._P * self._K

    @property
    def latency_s(self) -> float:
        """Average output latency of the STG's ring buffer (manual 6.3 formula)."""
        return (self.stg_ring_bytes / 4) / self.output_rate_Hz

    def stream_space(self) -> int:
        """Updates (carrier periods) that fit the PC queue of both channels now."""
        if self._dev is None or not self._P:
            return 0
        with self._io:
            space = min(int(self._dev.GetDataQueueSpace(self._u32(ch - 1)))
                        for ch in (self.ext_ch, self.flex_ch))
        return space // (self._P * self._K)

    def write_stream(self, I_ext_mA: np.ndarray, I_flex_mA: np.ndarray) -> None:
        """Queue one amplitude per channel per update; checked before anything is sent.

        Raises
        ------
        CurrentLimitError
            An amplitude above its stream ceiling, negative or not finite (nothing sent).
        SafetyError
            A previous stop failed (the STG may still run): switch it off first.
        DeviceError
            Not open, or the vendor refused the data.
        """
        if self._stop_error:
            raise SafetyError(f"STG: {self._stop_error}")
        if not self._P or self._dev is None or self._state not in (
                StimulatorState.ARMED, StimulatorState.RUNNING):
            raise DeviceError("no open stream; call open_stream() first")
        ext = np.asarray(I_ext_mA, dtype=float).ravel()
        flex = np.asarray(I_flex_mA, dtype=float).ravel()
        if ext.shape != flex.shape:
            raise CurrentLimitError("write_stream needs as many extensor as flexor "
                                    f"amplitudes ({ext.size} vs {flex.size}); nothing sent")
        for ch, a in ((self.ext_ch, ext), (self.flex_ch, flex)):
            limit = self._stream_ceiling[ch]
            bad = a[~np.isfinite(a) | (a < 0) | (a > limit)] if a.size else a
            if bad.size:
                raise CurrentLimitError(
                    f"streamed amplitude {bad[0]:.4g} mA on channel {ch} is outside 0 .. "
                    f"{limit:g} mA; nothing was sent")
        data = {ch: render_periods(np.repeat(a, self._K), self._P, self._range_nA[ch], self._q)
                for ch, a in ((self.ext_ch, ext), (self.flex_ch, flex))}
        for ch, v in data.items():   # the last check, on exactly what is sent
            peak_mA = np.abs(v.astype(np.int64)).max(initial=0) * self._range_nA[ch] \
                / (INT16_FULL - 1) / NA_PER_MA
            if peak_mA > self._stream_ceiling[ch] + 1e-9:
                raise CurrentLimitError(f"rendered peak {peak_mA:.4f} mA above the ceiling "
                                        f"on channel {ch}; nothing was sent")
        api = self.api
        n = len(ext) * self._P * self._K
        with self._io:
            # all or nothing: EnqueueData takes at most the free space (XML: "Returns the
            # number of enqueued bytes"), so a write that does not fit is refused whole
            space = min(int(self._dev.GetDataQueueSpace(self._u32(ch - 1))) for ch in data)
            self._check_drained(space)
            if n > space:
                raise DeviceError(f"the STG's PC ring buffer has room for {space} samples, "
                                  f"{n} were written; nothing was sent (ring_samples "
                                  f"{self.ring_samples})")
            for ch, v in data.items():
                dev_data = api.Array[api.Int16](v.tolist())
                got = int(self._dev.EnqueueData(self._u32(ch - 1), dev_data))
                if got != 2 * len(v):
                    self._error = (f"EnqueueData took {got} of {2 * len(v)} bytes on "
                                   f"channel {ch}")
                    raise DeviceError(f"STG streaming: {self._error}")
            sync = np.ones(n, dtype=np.uint16)
            self._dev.EnqueueSyncout(self._u32(self.sync_out - 1),
                                     api.Array[api.UInt16](sync.tolist()))
        self._enqueued += n
        self.enqueued_periods += len(ext) * self._K

    def _check_drained(self, space: int) -> None:
        """Raise :class:`StreamUnderrunError` if the PC queue drained less than a running
        STG must have drained by now (it stopped when it ran out of data, manual 6.3).

        A running STG has taken at least ``(elapsed - latency) x rate`` samples from the PC
        queue (its own ring holds at most :attr:`latency_s` of them); the queue tells how
        many it took: those enqueued less those still queued.
        """
        if self._t_start is None:
            return
        taken = self._enqueued - (self.ring_samples - space)
        elapsed_s = self._now() - self._t_start
        behind_s = elapsed_s - self.latency_s - UNDERRUN_SLACK_S - taken / self.output_rate_Hz
        if behind_s > 0:   # the trial ends (the interlock trips); the next stream is new
            raise StreamUnderrunError(
                f"the STG ran out of streamed data and stopped (McsUsbNet manual 6.3: it "
                f"stops when it runs out of data): the host fell {1e3 * behind_s:.0f} ms "
                "behind its queue; output is at zero. Queue more updates (a controller "
                "designed with a larger queue) or run on a less loaded PC")

    def start(self) -> None:
        """``SendStart(1)`` (manual 6.3: "by Software SendStart(1)"): the queued updates
        and the sync begin; sample 0 of the acquisition is this edge.

        Raises
        ------
        SafetyError
            A previous stop failed.
        DeviceError
            No open stream, or the vendor refused.
        """
        if self._stop_error:
            raise SafetyError(f"STG: {self._stop_error}")
        if self._dev is None or not self._P or self._state is not StimulatorState.ARMED:
            raise DeviceError("no open stream to start; call open_stream() first")
        with self._io:
            self._wait_primed()
            try:
                self._dev.SendStart(self._u32(1))
            except Exception as exc:
                self._state = StimulatorState.ERROR
                self._error = f"SendStart failed: {exc}"
                raise DeviceError(f"STG SendStart (streaming) failed: {exc}") from exc
        self._started = True
        self._t_start = self._now()    # after SendStart returned: the test stays conservative
        self._state = StimulatorState.RUNNING

    def _wait_primed(self) -> None:
        """Return once the STG's memory holds the queued data (or a full ring of it);
        raise DeviceError, starting nothing, if it does not within PRIME_TIMEOUT_S."""
        if self._enqueued <= 0:
            raise DeviceError("STG streaming: nothing queued to start (write_stream first); "
                              "nothing was started")
        dev = self._dev
        assert dev is not None
        need = min(self._enqueued, self.stg_ring_bytes // BYTES_PER_FRAME)
        deadline = time.monotonic() + PRIME_TIMEOUT_S
        while True:
            got = int(dev.GetFramesBuffered(self._u32(0)))    # trigger 1, 0-based
            if got >= need:
                return
            if time.monotonic() > deadline:
                raise DeviceError(
                    f"STG streaming: only {got} of {need} frames reached the STG's memory "
                    f"within {PRIME_TIMEOUT_S:g} s of StartLoop (McsUsbNet "
                    "GetFramesBuffered; manual 6.3: \"Give StartLoop some time\"); nothing "
                    "was started")
            time.sleep(0.002)

    def arm(self) -> None:
        """Nothing to do: :meth:`open_stream` armed trigger 1 (``StartLoop``)."""
        if self._state is not StimulatorState.ARMED:
            raise DeviceError("no open stream to arm; call open_stream() first")

    def stop_after_period(self) -> None:
        """An ordinary end or abort: the queued updates play out (whole carrier periods,
        then one at zero) before ``SendStop``; see :meth:`close_stream`. Never raises."""
        self.close_stream()

    def close_stream(self) -> str:
        """End after the queued updates: one zero period, wait until everything written has
        played (bounded), then ``SendStop`` and ``StopLoop``. Idempotent, never raises.

        Returns
        -------
        str
            An underrun found at close, in one line ("" when every update written for the
            trial played). With continuous mode disabled "the STG stops when it runs out of
            data" (manual 6.3); a stream whose data stopped reaching the STG (or whose last
            updates were written after it had stopped) after the host's last
            :meth:`write_stream` is seen only here: what was written less what is still
            queued on the PC (``GetDataQueueSpace``) or in the STG's memory
            (``GetFramesBuffered``, XML: "frames currently buffered in STG Memory") is what
            played, so the line says when the STG stopped and how much was not delivered.
            A second call returns the same answer (``run_block``'s stream hook asks after
            :meth:`stop_after_period` closed the stream).
        """
        if self._dev is None or not self._P:
            return self._close_underrun
        written = self._enqueued          # the trial's own updates (before the zero period)
        try:
            if self._state is StimulatorState.RUNNING:
                self._close_underrun = self._play_out(written)
        except Exception as exc:  # closing must not raise: the stop below still runs
            log.warning("STG stream close: %s", exc)
            self._close_underrun = (f"the STG's stream could not be confirmed played out at "
                                    f"close ({type(exc).__name__}: {exc}); output stopped")
        self._stop("close_stream")
        if self._close_underrun:
            log.error("STG stream close: %s", self._close_underrun)
        self._P = 0
        self._t_start = None
        return self._close_underrun

    def _play_out(self, written: int) -> str:
        """Let what is queued play, a zero period after it; return the underrun line ("" if
        all ``written`` samples played). The wait ends when the PC queue and the STG's
        memory are empty, or when a running STG must have played everything on the driver's
        clock (:attr:`latency_s` + :data:`UNDERRUN_SLACK_S` after the last sample's time;
        a real-time backstop for a clock that does not move)."""
        if self._queue_space() < self.ring_samples or self._frames_buffered() > 0:
            try:
                self.write_stream(np.zeros(1), np.zeros(1))
            except StreamUnderrunError as exc:   # stopped: nothing more will play
                log.info("STG stream close: %s", exc)
            else:
                t_start = self._t_start if self._t_start is not None else self._now()
                due_s = (t_start + self._enqueued / self.output_rate_Hz + self.latency_s
                         + UNDERRUN_SLACK_S)
                backstop = time.monotonic() + CLOSE_BACKSTOP_S + 10 * max(
                    0.0, due_s - self._now())
                while self._unplayed() > 0:
                    if self._now() > due_s or time.monotonic() > backstop:
                        break
                    time.sleep(0.002)
        played = self._enqueued - self._unplayed()
        if played >= written:
            return ""
        rate = self.output_rate_Hz
        return (f"the STG ran out of streamed data and stopped {played / rate:.3f} s into "
                f"the stream of {written / rate:.3f} s (McsUsbNet manual 6.3: with "
                f"continuous mode disabled it stops when it runs out of data); found at "
                f"close, no write had noticed it: the last {(written - played) / rate:.3f} s "
                f"were not delivered; output is at zero")

    def _unplayed(self) -> int:
        """Samples written and not played: still on the PC queue or in the STG's memory."""
        return self.ring_samples - self._queue_space() + self._frames_buffered()

    def _frames_buffered(self) -> int:
        dev = self._dev
        if dev is None:
            return 0
        with self._io:
            return int(dev.GetFramesBuffered(self._u32(0)))

    def _queue_space(self) -> int:
        dev = self._dev
        if dev is None:
            return self.ring_samples
        with self._io:
            return int(dev.GetDataQueueSpace(self._u32(self.ext_ch - 1)))

    # -- stop / status -------------------------------------------------------------------
    def _stop(self, why: str) -> None:
        dev = self._dev
        if dev is None:
            return
        with self._io:
            try:
                dev.SendStop(self._u32(1))
                log.info("STG (streaming) SendStop(1): %s", why)
            except Exception as exc:
                self._stop_error = (
                    f"SendStop failed ({exc}) during {why}: the STG may still be "
                    "stimulating; SWITCH THE STIMULATOR OFF at its power switch now")
                log.critical("STG: %s", self._stop_error)
            try:
                dev.StopLoop()
            except Exception as exc:  # the loop may already be gone with the device
                log.warning("STG StopLoop failed: %s", exc)
        self._started = False
        if self._state in (StimulatorState.RUNNING, StimulatorState.ARMED):
            self._state = StimulatorState.STOPPED

    def stop_now(self) -> None:
        """The immediate stop (E-stop): output at zero, the stream ended. Never raises."""
        self._stop("stop_now")
        self._P = 0

    def status(self) -> StimulatorStatus:
        return StimulatorStatus(state=self._state,
                                output_active=self._state is StimulatorState.RUNNING
                                or bool(self._stop_error),
                                error=self._stop_error or self._error)

    def load(self, waveform) -> None:
        raise DeviceError("the streaming STG driver takes no downloaded trials; use "
                          "open_stream / write_stream (or the download-mode driver)")

    def disconnect(self) -> None:
        if self._dev is None:
            return
        self.stop_now()
        dev, self._dev = self._dev, None
        for call in ("Disconnect", "Dispose"):
            try:
                getattr(dev, call)()
            except Exception as exc:
                log.warning("STG %s failed: %s", call, exc)
        self._state = StimulatorState.DISCONNECTED


class Stg4002WithStreaming(Stg4002Stimulator):
    """The STG4002 driver of download mode that also streams (the registry's driver).

    Trials and calibration steps are downloaded exactly as by
    :class:`~nmsid.drivers.stg4002.Stg4002Stimulator`; :meth:`open_stream` hands the device
    over to a :class:`StgStreamingStimulator` (one McsUsbNet connection at a time: the
    download handle is released first, its ``disconnect`` stops every trigger) and
    :meth:`close_stream` hands it back (the download handle connects again at the next
    :meth:`load`). While a stream is open, ``arm`` / ``start`` / ``stop_now`` /
    ``stop_after_period`` / ``status`` are the streaming driver's; ``stop_now`` always
    stops both, so an E-stop reaches whichever handle holds the device.

    Parameters
    ----------
    streaming : StgStreamingStimulator
        Built with the same channels, sync output, serial and ceilings.
    **kw
        As :class:`~nmsid.drivers.stg4002.Stg4002Stimulator`.
    """

    def __init__(self, *, streaming: StgStreamingStimulator, **kw):
        super().__init__(**kw)
        self.streaming = streaming
        self._streaming_open = False
        self._was_connected = False

    # -- the stream: the device handed over ------------------------------------------------
    def open_stream(self, ceiling_ext_mA: float, ceiling_flex_mA: float, update_Hz: float,
                    carrier_Hz: float | None = None) -> float:
        """Release the download handle, open the stream (see
        :meth:`StgStreamingStimulator.open_stream`)."""
        self._refuse_after_failed_stop()
        if self._dev is not None:
            self._was_connected = True
            self.disconnect()
        self._streaming_open = True
        try:
            return self.streaming.open_stream(ceiling_ext_mA, ceiling_flex_mA, update_Hz,
                                              carrier_Hz)
        except BaseException:
            self.close_stream()
            raise

    def write_stream(self, I_ext_mA: np.ndarray, I_flex_mA: np.ndarray) -> None:
        if not self._streaming_open:
            raise DeviceError("no open stream; call open_stream() first")
        self.streaming.write_stream(I_ext_mA, I_flex_mA)

    def stream_space(self) -> int:
        return self.streaming.stream_space() if self._streaming_open else 0

    def close_stream(self) -> str:
        """End the stream (output to zero) and release its handle. Idempotent, never
        raises. Returns the underrun found at close (see
        :meth:`StgStreamingStimulator.close_stream`; "" if none), the same answer on every
        call until the next stream opens."""
        if not self._streaming_open:
            return self.streaming.close_stream()
        underrun = ""
        try:
            underrun = self.streaming.close_stream()
        finally:
            err = str(getattr(self.streaming, "_stop_error", ""))
            self.streaming.disconnect()
            if err and not getattr(self, "_stop_error", ""):
                self._stop_error = err   # a failed stop stays: this driver refuses to start
            self._streaming_open = False
        if self._was_connected and not err:
            # the download handle back at once: between trials the engine asks status()
            # of a connected stimulator (a disconnected one reads as a lost link)
            try:
                self.connect()
            except Exception as exc:
                log.error("STG: download connection after the stream failed: %s", exc)
        return underrun

    @property
    def streaming_open(self) -> bool:
        """A stream holds the device."""
        return self._streaming_open

    # -- the Stimulator methods, routed ----------------------------------------------------
    def load(self, waveform) -> None:
        if self._streaming_open:
            raise DeviceError("a stream is open on the STG; close it before loading a trial")
        if self._dev is None and self._was_connected:
            self.connect()
        super().load(waveform)

    def arm(self) -> None:
        if self._streaming_open:
            self.streaming.arm()
        else:
            super().arm()

    def start(self) -> None:
        if self._streaming_open:
            self._refuse_after_failed_stop()
            self.streaming.start()
        else:
            super().start()

    def stop_after_period(self) -> None:
        if self._streaming_open:
            self.streaming.stop_after_period()
        else:
            super().stop_after_period()

    def stop_now(self) -> None:
        """The immediate stop of whichever handle holds the device (both asked). Never
        raises."""
        try:
            self.streaming.stop_now()
        finally:
            super().stop_now()

    def status(self) -> StimulatorStatus:
        if self._streaming_open:
            return self.streaming.status()
        return super().status()

    def capabilities(self) -> StimulatorCapabilities:
        if self._caps is None and self._streaming_open:
            return self.streaming.capabilities()
        return super().capabilities()

    def disconnect(self) -> None:
        if self._streaming_open:
            self.close_stream()
        super().disconnect()
