"""The simulated rig: :func:`make_sim_rig` builds the devices the engine drives."""

from __future__ import annotations

from dataclasses import dataclass, field

from nmsid.drivers.interfaces import RigDevices
from nmsid.sim_backends.acquisition import SimForceAcquisition
from nmsid.sim_backends.clocks import FastClock, SimRealClock
from nmsid.sim_backends.errors import DeviceStateError, SimConfigError
from nmsid.sim_backends.estop import SimEStop
from nmsid.sim_backends.faults import Fault, FaultScript
from nmsid.sim_backends.participant import VirtualParticipant, default_participant
from nmsid.sim_backends.stimulator import SimStimulator
from nmsid.sim_backends.world import SimWorld

FAST_CHUNK_S = 0.1
"""Chunk length on the fast clock (long chunks: fewer calls, faster sessions)."""
REALTIME_CHUNK_S = 0.02
"""Chunk length in real time (short chunks: latency measurements mean something)."""
FAST_BLOCK_S = 15.0
"""Simulated ahead per step on the fast clock (a whole trial: fewest calls)."""
REALTIME_BLOCK_S = 1.0
"""Simulated ahead per step in real time (keeps the simulation lock held briefly)."""


@dataclass
class SimRig(RigDevices):
    """The simulated devices plus what tests need to look inside.

    ``participant``: the virtual participant; ``world``: the shared time base and the
    stimulator's history (``world.records``, ``world.output_zero``, ``world.stop_calls``);
    ``faults``: the fault script and its ``fired`` log.
    """

    participant: VirtualParticipant | None = None
    """The template participant, or another with its interface (``MskParticipant``)."""
    world: SimWorld | None = None
    faults: FaultScript = field(default_factory=FaultScript)

    @property
    def max_sent_mA(self) -> tuple[float, float]:
        """Largest current ever loaded per channel (extensor, flexor), mA."""
        w = self._sim_world()
        return float(w.max_sent_mA[0]), float(w.max_sent_mA[1])

    @property
    def max_delivered_mA(self) -> tuple[float, float]:
        """Largest current ever output per channel (extensor, flexor), mA."""
        w = self._sim_world()
        return float(w.max_delivered_mA[0]), float(w.max_delivered_mA[1])

    @property
    def output_zero_events(self):
        """Every time the output became zero by ``stop_now`` or a stimulator fault."""
        w = self._sim_world()
        with w.lock:
            w.update()      # a stop requested a moment ago is recorded now
            return list(w.output_zero)

    @property
    def run_records(self):
        """One record per stimulator start: trigger time and sample, end, reason, peaks."""
        return list(self._sim_world().records)

    @property
    def cumulative_stim_s(self) -> float:
        """Stimulation time the participant has received since the rig was made, s."""
        return self._sim_world().sim.cumulative_stim_s

    def add_fault(self, fault: Fault) -> None:
        """Schedule a fault after the rig was made (``session_s`` counts from the rig's
        creation; a ``trial`` / ``run`` index must not have started yet)."""
        self._sim_world().add_fault(fault)

    def true_parameters(self, sE: float, calibration=None):
        """Shortcut for ``participant.true_parameters``."""
        if self.participant is None:
            raise DeviceStateError("this simulated rig has no participant")
        return self.participant.true_parameters(sE, calibration)

    def _sim_world(self) -> SimWorld:
        if self.world is None:
            raise DeviceStateError("this simulated rig has no simulated world")
        return self.world


def make_sim_rig(participant: VirtualParticipant | None = None, *, realtime: bool = False,
                 faults: FaultScript | list[Fault] | None = None, seed: int = 0,
                 fs_Hz: float = 2000.0, chunk_s: float | None = None,
                 connect: bool = False) -> SimRig:
    """Build a simulated rig.

    Parameters
    ----------
    participant : VirtualParticipant or MskParticipant, optional
        Who is on the rig; default :func:`~nmsid.sim_backends.participant.default_participant`
        with ``seed``. Any participant with ``make_simulator(fs_Hz)``, ``sensor``,
        ``seed`` and ``true_parameters`` works (the musculoskeletal one:
        :func:`nmsid.sim_backends.msk_participant.default_msk_participant`).
    realtime : bool
        False: :class:`FastClock` (virtual time, as fast as possible). True: real time.
    faults : FaultScript or list of Fault, optional
        Faults to inject.
    seed : int
        Seed of the default participant (ignored when ``participant`` is given: its own
        ``seed`` sets its noise).
    fs_Hz : float
        Acquisition rate (the paper: 2000 Hz).
    chunk_s : float, optional
        Acquisition chunk length; default 0.1 s on the fast clock, 0.02 s in real time.
    connect : bool
        Connect the stimulator already (the engine normally does it).

    Returns
    -------
    SimRig
        A :class:`nmsid.drivers.interfaces.RigDevices` with ``backend="sim"``.

    Examples
    --------
    >>> rig = make_sim_rig()
    >>> rig.backend, rig.stimulator.capabilities().max_current_mA
    ('sim', 16.0)
    """
    if participant is None:
        participant = default_participant(seed=seed)
    if not (isinstance(participant, VirtualParticipant)
            or callable(getattr(participant, "make_simulator", None))):
        raise SimConfigError(f"participant must be a VirtualParticipant or have "
                             f"make_simulator(fs_Hz) (e.g. an MskParticipant), got "
                             f"{type(participant).__name__}")
    if isinstance(faults, (list, tuple)):
        faults = FaultScript(list(faults))
    script = faults if faults is not None else FaultScript()
    clock = SimRealClock() if realtime else FastClock()
    if chunk_s is None:
        chunk_s = REALTIME_CHUNK_S if realtime else FAST_CHUNK_S
    if not 0 < chunk_s <= 1.0:
        raise SimConfigError(f"chunk_s must be in (0, 1] s, got {chunk_s!r}")
    world = SimWorld(participant, clock, script, fs_Hz=fs_Hz, chunk_s=chunk_s,
                     block_s=REALTIME_BLOCK_S if realtime else FAST_BLOCK_S)
    stim = SimStimulator(world)
    if connect:
        stim.connect()
    return SimRig(stimulator=stim, acquisition=SimForceAcquisition(world),
                  estop=SimEStop(world), clock=clock, backend="sim",
                  participant=participant, world=world, faults=script)
