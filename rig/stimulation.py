"""One block of stimulation with hardware-timed acquisition, watched by the interlock.

:func:`run_block` loads a checked waveform, starts the acquisition (triggered, so sample 0
is stimulation onset), starts output through the interlock's gate, and collects the force
chunk by chunk, checking every interlock rule after each chunk and asking the caller
whether to stop (operator commands). Output goes to zero in a ``finally`` on every exit
path. The engine uses it for calibration steps and for trials.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from nmsid.drivers.interfaces import PeriodSafeStop
from nmsid.rig.safety import Interlock, InterlockTripped, Trip

log = logging.getLogger(__name__)

#: Real-time backstop of the stall rule, for clocks that do not advance while a read
#: waits: at least this many real seconds and 10 stall timeouts.
STALL_BACKSTOP_S = 1.0


@dataclass(eq=False)
class BlockResult:
    """What one block recorded."""

    received: int
    """Samples received from onset (all of them unless aborted)."""
    force_N: np.ndarray
    """Length n; samples at and after ``received`` are zero (not recorded)."""
    wrench: np.ndarray | None
    sync: np.ndarray | None
    abort_reason: str
    """Empty when every sample arrived."""


def _has_trigger(stim) -> bool:
    try:
        return bool(stim.capabilities().hardware_trigger)
    except Exception:  # a driver that cannot say: assume the trigger (the STG's behaviour)
        log.exception("stimulator.capabilities() failed")
        return True


def _reason(trip) -> str:
    return f"{trip.rule}: {trip.detail}"


def run_block(devices, interlock: Interlock, checked, n: int, *,
              on_samples: Callable[..., None] | None = None,
              should_stop: Callable[[], str] | None = None,
              on_chunk: Callable[..., None] | None = None,
              stream=None) -> BlockResult:
    """Stimulate ``checked`` and record ``n`` samples of force.

    Parameters
    ----------
    devices : drivers.interfaces.RigDevices
    interlock : rig.safety.Interlock
    checked : drivers.interfaces.CheckedWaveform
    n : int
        Samples to record (the waveform's length).
    on_samples : callable(lo, hi, force_N, wrench, sync), optional
        Called with each new run of samples ``[lo, hi)``; ``wrench`` (rows of 6) and
        ``sync`` are None when the acquisition does not record them.
    should_stop : callable() -> str, optional
        Asked after every chunk; a non-empty answer stops the block with that reason.
    on_chunk : callable(ForceChunk), optional
        Called with every chunk as the acquisition delivered it (the dry run keeps its
        monitor input), before the interlock's checks of it.
    stream : optional
        Closed loop (:mod:`nmsid.rig.tracking`): ``checked`` is None and the stimulation
        is streamed: ``stream.open(stimulator)`` opens and prefills the stream instead
        of loading a waveform, ``stream.update(received, force_N)`` writes the next
        updates after each chunk's samples are stored (same interlock checks, same
        stop), ``stream.close(stimulator)`` runs after the output went to zero; a
        non-empty answer (the driver found at close that the device ran out of data and
        stopped early) trips the interlock and becomes (or is added to) the abort reason.

    Returns
    -------
    BlockResult
    """
    stim, acq, clock = devices.stimulator, devices.acquisition, devices.clock
    force = np.zeros(n)
    wrench = sync = None
    received = 0
    try:
        if stream is None:
            stim.load(checked)
        else:
            stream.open(stim)
        stim.arm()
    except Exception as exc:  # a driver fault before any output: trip, nothing started
        trip: Trip | None = interlock.stimulator_fault(f"stimulator refused the waveform "
                                          f"({type(exc).__name__}: {exc})")
        return BlockResult(0, force, None, None, _reason(trip))
    try:
        # sample 0 = the stimulator's start trigger; a device without a trigger output
        # (capabilities().hardware_trigger False) gets the acquisition started by the host
        # just before its output starts
        acq.start(n, triggered=_has_trigger(stim))
    except Exception as exc:
        trip = interlock.acquisition_fault(f"acquisition could not start "
                                           f"({type(exc).__name__}: {exc})")
        return BlockResult(0, force, None, None, _reason(trip))
    stall_limit_real = max(STALL_BACKSTOP_S, 10 * interlock.stall_timeout_s)
    read_timeout = min(0.05, interlock.stall_timeout_s / 2)
    reason = ""
    try:
        # the stall limit allows for chunked delivery and a stepped clock (Windows):
        # drivers may declare their chunk period; otherwise it is learnt from the chunks
        interlock.watch_stream(clock.monotonic_s(), fs_Hz=getattr(checked, "fs_Hz", None),
                               chunk_period_s=getattr(acq, "chunk_period_s", None))
        interlock.start_output()
        last_real = time.monotonic()
        while received < n:
            try:
                chunk = acq.read(read_timeout)
            except Exception as exc:  # the force chain failed: a sensor fault
                reason = _reason(interlock.acquisition_fault(
                    f"acquisition read failed ({type(exc).__name__}: {exc})"))
                break
            now = clock.monotonic_s()
            if chunk is not None and on_chunk is not None:
                on_chunk(chunk)
            if chunk is not None and (chunk.n or chunk.flags.any):
                # an empty chunk may still carry flags (overrun, sensor fault): check them
                if chunk.n:
                    last_real = time.monotonic()
                trip = interlock.check_chunk(chunk, now, expected_index=received)
                k0 = chunk.start_index
                lo, hi = max(k0, received), min(k0 + chunk.n, n)
                if hi > lo:
                    seg = slice(lo - k0, hi - k0)
                    force[lo:hi] = chunk.force_N[seg]
                    if chunk.wrench is not None:
                        if wrench is None:
                            wrench = np.zeros((n, 6))
                        wrench[lo:hi] = np.asarray(chunk.wrench)[seg]
                    if chunk.sync is not None:
                        if sync is None:
                            sync = np.zeros(n)
                        sync[lo:hi] = np.asarray(chunk.sync)[seg]
                    if lo > received:  # a gap (only without trip_on_overrun): NaN-fill
                        force[received:lo] = np.nan
                    received = hi
                    if on_samples is not None:
                        on_samples(lo, hi, force[lo:hi],
                                   None if wrench is None else wrench[lo:hi],
                                   None if sync is None else sync[lo:hi])
                    if stream is not None and trip is None:
                        stream.update(received, force)
                if trip is not None:
                    reason = _reason(trip)
                    break
            if chunk is None or not chunk.n:
                trip = interlock.check_stall(now)
                gap_real = time.monotonic() - last_real
                if trip is None and gap_real > stall_limit_real:
                    trip = interlock.stream_stalled(f"no force samples for "
                                                    f"{gap_real:.1f} s (real time)")
                if trip is not None:
                    reason = _reason(trip)
                    break
            trip = interlock.check_stimulator() or interlock.check_switch()
            if trip is not None:
                reason = _reason(trip)
                break
            if interlock.latched:  # an E-stop from another thread
                t = interlock.trip_info
                reason = _reason(t) if t else "interlock latched"
                break
            if should_stop is not None:
                reason = should_stop()
                if reason:
                    break
    except InterlockTripped as exc:
        reason = str(exc)
    except Exception as exc:  # a driver raised mid-run: a fault like any other
        reason = _reason(interlock.stimulator_fault(f"device error "
                                                    f"({type(exc).__name__}: {exc})"))
    finally:
        try:
            if not interlock.latched and isinstance(stim, PeriodSafeStop):
                # an ordinary end or an operator's abort: never cut a carrier period
                stim.stop_after_period()
            else:   # an E-stop, a trip or a fault: output to zero at once
                stim.stop_now()
        except Exception:
            log.exception("stopping the stimulator failed")
            try:
                stim.stop_now()
            except Exception:
                log.exception("stimulator.stop_now() failed")
        interlock.unwatch_stream()
        if stream is not None:
            try:
                underrun = stream.close(stim)
            except Exception:
                log.exception("closing the stimulation stream failed")
                underrun = ""
            if underrun:
                # found only at close (the STG ran dry after the host's last write): the
                # trial did not deliver what it recorded; a fault as one found mid-stream
                # (output to zero, the interlock's trip event, the trial aborted)
                interlock.stimulator_fault(underrun)
                found = f"{interlock.stim.name}: {underrun}"
                reason = found if not reason else f"{reason}; also {found}"
        try:
            acq.stop()
        except Exception:
            log.exception("acquisition.stop() failed")
    return BlockResult(received, force, wrench, sync, reason)
