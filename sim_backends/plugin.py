"""A lab's own participant model on the simulated rig: ``--participant-model pkg.mod:factory``.

The plug-in interface (``docs/control.md``, "Your own participant")::

    def factory(seed: int, fs_Hz: float):
        return model            # any object with force_N(I_ext_mA, I_flex_mA)

    model.force_N(I_ext_mA, I_flex_mA) -> ndarray

``force_N`` is called with consecutive blocks of samples at ``fs_Hz`` (1-D float arrays of
the carrier amplitude really delivered on each channel, mA; 0 while the output is off) and
returns the endpoint force of each sample (N, extension positive), keeping its own state
between calls. The rig adds its force chain (the template participant's sensor model:
noise, offset, range) to what the model returns.

The built-in participants speak the same interface through :class:`BuiltinForceModel`
(factories :func:`template` and :func:`musculoskeletal`), so
``--participant-model nmsid.sim_backends.plugin:template`` runs the template participant
through the plug-in path.

The rig never copies a plug-in. A model may offer two optional methods::

    model.snapshot() -> state      # everything needed to continue exactly from here
    model.restore(state)           # return there (a state may be restored more than once)

With them the simulated rig simulates ahead in blocks and rolls back when the output
changes (an E-stop, a streamed update); without them it runs the model forward only: each
block of samples is computed when the acquisition hands it out, never ahead, so nothing
ever needs undoing (slower for small blocks, exact). A model holding a module, a lock, a
compiled simulator or an FMU instance needs neither method
(:mod:`nmsid.sim_backends.fmu_participant` is such a plug-in).

A plug-in's exceptions, ``sys.exit`` included, become one
:class:`ParticipantPluginError` line naming the spec; during a session the acquisition
fails and the interlock stops the output.
"""

from __future__ import annotations

import importlib
import math
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from nmsid.sim_backends.errors import SimConfigError
from nmsid.sim_backends.msk_participant import default_msk_participant
from nmsid.sim_backends.participant import default_participant
from nmsid.sim_backends.sensor import SensorModel, SensorState
from nmsid.sim_backends.simulation import SimulatedBlock, simulator_for

QUIET_PIECE_SAMPLES = 4000
"""A rest is handed to the plug-in in blocks of at most this many zero samples."""


PROBE_FS_HZ = 2000.0
PROBE_SAMPLES = 64
PROBE_MAX_MA = 8.0
"""A spec is checked when it is named, the way the session will run it (at the session's
sample rate, forward only unless it offers snapshot/restore): a fresh model is given 64
zero samples, then 64 samples ramping both channels to 8 mA, and must answer with 64
finite forces each time."""


class ParticipantPluginError(SimConfigError):
    """A ``--participant-model`` plug-in cannot be loaded or returned a bad force."""


def parse_spec(spec: str) -> tuple[str, str]:
    """``"package.module:factory"`` -> ``("package.module", "factory")``.

    Raises
    ------
    ParticipantPluginError
        Without exactly one colon, or with an empty or non-identifier part.
    """
    text = str(spec)
    if text.count(":") != 1:
        raise ParticipantPluginError(
            f"--participant-model {text!r}: a plug-in is named 'package.module:factory' "
            "(one colon), or one of: template, musculoskeletal")
    mod, fac = (p.strip() for p in text.split(":"))
    if not mod or not all(part.isidentifier() for part in mod.split(".")) \
            or not fac.isidentifier():
        raise ParticipantPluginError(
            f"--participant-model {text!r}: {mod!r} must be a dotted module name and "
            f"{fac!r} a function name ('package.module:factory')")
    return mod, fac


def load_factory(spec: str) -> Callable[..., Any]:
    """Import the factory a spec names (the current directory is searched too).

    Raises
    ------
    ParticipantPluginError
        If the module cannot be imported, has no such name, or it is not callable.
    """
    mod_name, fac_name = parse_spec(spec)
    cwd = str(Path.cwd())
    added = cwd not in sys.path
    if added:
        sys.path.append(cwd)   # "importable from the environment or the current directory"
    try:
        module = importlib.import_module(mod_name)
    except ModuleNotFoundError as exc:
        raise ParticipantPluginError(
            f"--participant-model {spec!r}: module {mod_name!r} not found ({exc.name!r} is "
            f"not importable from the environment or the current directory {cwd})") from None
    except KeyboardInterrupt:
        raise
    except BaseException as exc:  # noqa: BLE001 - the lab's module failed to import (or
        # called sys.exit at import): one line
        raise ParticipantPluginError(
            f"--participant-model {spec!r}: importing {mod_name!r} failed: "
            f"{_what(exc)}") from None
    finally:
        if added:
            try:
                sys.path.remove(cwd)
            except ValueError:
                pass
    factory = getattr(module, fac_name, None)
    if factory is None:
        raise ParticipantPluginError(f"--participant-model {spec!r}: module {mod_name!r} has "
                                     f"no {fac_name!r}")
    if not callable(factory):
        raise ParticipantPluginError(f"--participant-model {spec!r}: {fac_name!r} is a "
                                     f"{type(factory).__name__}, not a callable factory")
    return factory


def _what(exc: BaseException) -> str:
    """A plug-in's exception in words (``sys.exit(0)`` is named as such)."""
    if isinstance(exc, SystemExit):
        return f"it called sys.exit({exc.code!r})"
    return f"{type(exc).__name__}: {exc}"


def checked_force(spec: str, out: Any, n: int, first_sample: int) -> np.ndarray:
    """The plug-in's answer as a float array of length ``n``, finite, or one line why not."""
    try:
        arr = np.asarray(out, dtype=float)
    except (TypeError, ValueError):
        raise ParticipantPluginError(
            f"participant plug-in {spec!r}: force_N returned {type(out).__name__}, not an "
            "array of numbers") from None
    if arr.shape != (n,):
        raise ParticipantPluginError(
            f"participant plug-in {spec!r}: force_N returned shape {arr.shape} for a block "
            f"of {n} samples; it must return one force per sample, shape ({n},)")
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        raise ParticipantPluginError(
            f"participant plug-in {spec!r}: force_N returned {arr[bad[0]]!r} at sample "
            f"{first_sample + int(bad[0])}; every force must be a finite number of N")
    return arr


@dataclass(frozen=True, eq=False)
class PluginParticipant:
    """A participant of the simulated rig built by a lab's factory.

    Parameters
    ----------
    spec : str
        ``package.module:factory`` (for messages and the session file).
    factory : callable(seed, fs_Hz)
        Returns the model (an object with ``force_N``).
    seed : int
        Passed to the factory; also seeds the force chain's noise.
    code : str
        Participant code.
    sensor : SensorModel
        The force chain the rig puts after the model.
    """

    spec: str
    factory: Callable[..., Any]
    seed: int = 0
    code: str = "PLUGIN"
    sensor: SensorModel = field(default_factory=SensorModel)

    def make_model(self, fs_Hz: float):
        """Call the factory; check the object it returns has ``force_N``."""
        try:
            model = self.factory(int(self.seed), float(fs_Hz))
        except KeyboardInterrupt:
            raise
        except BaseException as exc:  # noqa: BLE001 - the lab's code failed or called
            # sys.exit: one line, named (a plug-in never ends the session's process)
            raise ParticipantPluginError(
                f"participant plug-in {self.spec!r}: factory(seed={self.seed}, "
                f"fs_Hz={fs_Hz:g}) failed: {_what(exc)}") from None
        if not callable(getattr(model, "force_N", None)):
            raise ParticipantPluginError(
                f"participant plug-in {self.spec!r}: the factory returned a "
                f"{type(model).__name__} without a force_N(I_ext_mA, I_flex_mA) method")
        return model

    def make_simulator(self, fs_Hz: float) -> PluginSimulator:
        """The rig's stateful simulator of this participant."""
        return PluginSimulator(self, fs_Hz)

    def true_parameters(self, sE: float, calibration=None):
        """A plug-in has no known second-order truth."""
        raise ParticipantPluginError(f"participant plug-in {self.spec!r} has no known "
                                     "true parameters (only nmsid's own participants do)")

    def effect_truth(self) -> list[dict]:
        return []


class PluginSimulator:
    """The simulated rig's view of a plug-in: the interface of
    :class:`nmsid.sim_backends.simulation.ParticipantSimulator` (``simulate``,
    ``advance_quiet``, ``snapshot`` / ``restore``, ``cursor``, ``cumulative_stim_s``)."""

    def __init__(self, participant: PluginParticipant, fs_Hz: float = 2000.0):
        self.p = participant
        self.fs_Hz = float(fs_Hz)
        self.model = participant.make_model(self.fs_Hz)
        self.cursor = 0
        self.stim_samples = 0
        self.sensor = SensorState(participant.sensor, participant.seed, self.fs_Hz)

    def _force(self, I_e: np.ndarray, I_f: np.ndarray) -> np.ndarray:
        try:
            out = self.model.force_N(I_e.copy(), I_f.copy())
        except (ParticipantPluginError, KeyboardInterrupt):
            raise
        except BaseException as exc:  # noqa: BLE001 - the lab's code failed or called
            # sys.exit: one line, named; the rig's interlock stops the output
            raise ParticipantPluginError(
                f"participant plug-in {self.p.spec!r}: force_N failed at sample "
                f"{self.cursor}: {_what(exc)}") from None
        return checked_force(self.p.spec, out, I_e.size, self.cursor)

    def simulate(self, I_ext_mA: np.ndarray, I_flex_mA: np.ndarray, *,
                 spike_N: np.ndarray | None = None) -> SimulatedBlock:
        """Simulate the next ``len(I_ext_mA)`` samples from the cursor."""
        I_e = np.asarray(I_ext_mA, dtype=float)
        I_f = np.asarray(I_flex_mA, dtype=float)
        n0 = self.cursor
        y = self._force(I_e, I_f)
        self.stim_samples += int(np.count_nonzero((I_e > 0) | (I_f > 0)))
        self.cursor = n0 + I_e.size
        force, wrench, over = self.sensor.measure(y if spike_N is None else y + spike_N, n0)
        return SimulatedBlock(n0, y, force, wrench, over, math.nan, self.cumulative_stim_s)

    def advance_quiet(self, n: int) -> None:
        """Let ``n`` samples pass without stimulation: the model sees them all (zeros)."""
        done = 0
        while done < n:
            m = min(QUIET_PIECE_SAMPLES, n - done)
            z = np.zeros(m)
            self._force(z, z)
            self.cursor += m
            done += m

    @property
    def forward_only(self) -> bool:
        """The model offers no ``snapshot`` / ``restore``: the rig never simulates ahead."""
        return not (callable(getattr(self.model, "snapshot", None))
                    and callable(getattr(self.model, "restore", None)))

    def snapshot(self) -> tuple:
        """The whole state (the model's own :meth:`snapshot`; None for a forward-only
        model, which is never rolled back)."""
        state = None if self.forward_only else self._call("snapshot")
        return (self.cursor, self.stim_samples, state)

    def restore(self, snap: tuple) -> None:
        cursor, stim_samples, state = snap
        if cursor == self.cursor and stim_samples == self.stim_samples:
            return   # nothing simulated since: nothing to undo
        if self.forward_only:
            raise ParticipantPluginError(
                f"participant plug-in {self.p.spec!r} runs forward only (no snapshot/"
                "restore) and cannot be rolled back")
        self._call("restore", state)
        self.cursor, self.stim_samples = cursor, stim_samples

    def _call(self, name: str, *args):
        try:
            return getattr(self.model, name)(*args)
        except KeyboardInterrupt:
            raise
        except BaseException as exc:  # noqa: BLE001 - the lab's code: one line, named
            raise ParticipantPluginError(f"participant plug-in {self.p.spec!r}: {name}() "
                                         f"failed: {_what(exc)}") from None

    @property
    def cumulative_stim_s(self) -> float:
        return self.stim_samples / self.fs_Hz


def plugin_participant(spec: str, seed: int = 0, code: str = "PLUGIN",
                       fs_Hz: float = PROBE_FS_HZ) -> PluginParticipant:
    """The participant a ``package.module:factory`` spec names (its factory checked now).

    Raises
    ------
    ParticipantPluginError
        One line naming the spec and what is wrong.
    """
    participant = PluginParticipant(spec=str(spec), factory=load_factory(spec),
                                    seed=int(seed), code=code)
    probe = PluginSimulator(participant, fs_Hz)   # a throwaway model: fail now, not
    ramp = np.linspace(0.0, PROBE_MAX_MA, PROBE_SAMPLES)  # in the middle of a session
    probe.simulate(np.zeros(PROBE_SAMPLES), np.zeros(PROBE_SAMPLES))
    snap = None if probe.forward_only else probe.snapshot()
    probe.simulate(ramp, ramp)
    if snap is not None:   # the rig will roll it back: check that it can
        probe.restore(snap)
        probe.simulate(ramp, ramp)
    return participant


# -- the built-in participants through the same interface ------------------------------
class BuiltinForceModel:
    """A built-in participant behind the plug-in interface: ``force_N`` is its simulator's
    true endpoint force (the rig adds the sensor chain, as for any plug-in)."""

    def __init__(self, participant, fs_Hz: float):
        self._sim = simulator_for(participant, fs_Hz)

    def force_N(self, I_ext_mA: np.ndarray, I_flex_mA: np.ndarray) -> np.ndarray:
        return self._sim.simulate(I_ext_mA, I_flex_mA).true_force_N


def template(seed: int, fs_Hz: float) -> BuiltinForceModel:
    """Plug-in factory of the template participant (``default_participant(seed)``)."""
    return BuiltinForceModel(default_participant(seed=int(seed)), fs_Hz)


def musculoskeletal(seed: int, fs_Hz: float) -> BuiltinForceModel:
    """Plug-in factory of the MuJoCo participant (needs the ``mujoco`` extra)."""
    return BuiltinForceModel(default_msk_participant(seed=int(seed)), fs_Hz)
