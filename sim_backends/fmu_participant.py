"""A participant plug-in that is its own exported twin: an FMU run through FMPy.

``nmsid twin export`` writes a participant's twin as an FMI 2.0 co-simulation FMU (inputs
``rE`` and ``sE``, output ``force_N``; ``docs/fmu.md``). This module runs such an FMU as
the simulated rig's participant (``--participant-model
nmsid.sim_backends.fmu_participant:make``), and is the example of a plug-in the rig cannot
copy: the model holds an FMU instance (a loaded shared library and its C state), so it
offers no ``snapshot`` / ``restore`` and the rig runs it forward only
(:mod:`nmsid.sim_backends.plugin`).

The rig hands the plug-in the two currents; the FMU wants (rE, sE). Paper eqs. (1)-(4)
with the twin's calibration map them: ``Ie = (I_ext - Iemin) / (Iemax - Iemin)`` (0 below
Imin), likewise ``If``, ``sE = Ie + If``, ``rE = Ie / sE`` (0.5 at rest). The FMU is
stepped once per sample (``doStep`` of ``1 / fs_Hz``).

The factory :func:`make` reads the FMU's path from the environment variable
``NMSID_TWIN_FMU`` and the calibration (``Iemin,Iemax,Ifmin,Ifmax`` in mA) from
``NMSID_TWIN_CALIBRATION`` (default: the simulator's reference participant, 2, 9.5, 1.5,
8 mA). A lab's own module may instead build :class:`FmuParticipant` with its own values.
The twin's force starts at a step above Imin (the model has no recruitment threshold of its
own), so a session on it takes a manual calibration (``[calibration.manual]``).
"""

from __future__ import annotations

import os
import shutil
import tempfile

import numpy as np

from nmsid.sim_backends.errors import SimConfigError

FMU_ENV = "NMSID_TWIN_FMU"
CALIBRATION_ENV = "NMSID_TWIN_CALIBRATION"
DEFAULT_CALIBRATION_mA = (2.0, 9.5, 1.5, 8.0)


class FmuParticipant:
    """The twin FMU as a plug-in model: ``force_N(I_ext_mA, I_flex_mA)``, forward only.

    Parameters
    ----------
    fmu_path : path-like
        The ``.fmu`` written by ``nmsid twin export``.
    fs_Hz : float
        The rig's sample rate (one ``doStep`` per sample).
    calibration_mA : (float, float, float, float)
        ``Iemin, Iemax, Ifmin, Ifmax``.

    Raises
    ------
    SimConfigError
        If FMPy is missing, the file is not such an FMU, or the calibration is not
        ``0 < Imin < Imax`` per muscle.
    """

    def __init__(self, fmu_path, fs_Hz: float, calibration_mA=DEFAULT_CALIBRATION_mA):
        try:   # lazy: FMPy is an optional dependency of this one plug-in
            from fmpy import extract, read_model_description
            from fmpy.fmi2 import FMU2Slave
        except ImportError:
            raise SimConfigError("the FMU participant needs FMPy (pip install fmpy)") from None
        Iemin, Iemax, Ifmin, Ifmax = (float(x) for x in calibration_mA)
        if not (0 < Iemin < Iemax and 0 < Ifmin < Ifmax and np.isfinite(
                [Iemin, Iemax, Ifmin, Ifmax]).all()):
            raise SimConfigError(f"FMU participant: calibration {tuple(calibration_mA)!r} "
                                 "must be 0 < Imin < Imax per muscle (mA)")
        self.cal = (Iemin, Iemax, Ifmin, Ifmax)
        self.dt_s = 1.0 / float(fs_Hz)
        self.t_s = 0.0
        try:
            md = read_model_description(str(fmu_path))
        except Exception as exc:  # noqa: BLE001 - FMPy's many errors: one line
            raise SimConfigError(f"FMU participant: {fmu_path} is not a readable FMU "
                                 f"({type(exc).__name__}: {exc})") from None
        vr = {v.name: v.valueReference for v in md.modelVariables}
        missing = {"rE", "sE", "force_N"} - set(vr)
        if missing or md.coSimulation is None:
            raise SimConfigError(f"FMU participant: {fmu_path} is not a twin FMU (needs "
                                 "co-simulation and variables rE, sE, force_N)")
        self._vr_in = [vr["rE"], vr["sE"]]
        self._vr_out = [vr["force_N"]]
        self._dir = tempfile.mkdtemp(prefix="nmsid-fmu-")
        extract(str(fmu_path), self._dir)
        self.fmu = FMU2Slave(guid=md.guid, unzipDirectory=self._dir,
                             modelIdentifier=md.coSimulation.modelIdentifier,
                             instanceName="participant")
        self.fmu.instantiate()
        self.fmu.setupExperiment(startTime=0.0)
        self.fmu.enterInitializationMode()
        self.fmu.exitInitializationMode()

    def _rE_sE(self, I_e: float, I_f: float) -> tuple[float, float]:
        Iemin, Iemax, Ifmin, Ifmax = self.cal
        Ie = max(0.0, (I_e - Iemin) / (Iemax - Iemin))
        If = max(0.0, (I_f - Ifmin) / (Ifmax - Ifmin))
        sE = Ie + If
        return (Ie / sE if sE > 0 else 0.5), sE

    def force_N(self, I_ext_mA: np.ndarray, I_flex_mA: np.ndarray) -> np.ndarray:
        """One FMU step per sample; the force at the end of each step."""
        out = np.empty(len(I_ext_mA))
        for k, (Ie, If) in enumerate(zip(I_ext_mA, I_flex_mA, strict=True)):
            self.fmu.setReal(self._vr_in, list(self._rE_sE(float(Ie), float(If))))
            self.fmu.doStep(currentCommunicationPoint=self.t_s,
                            communicationStepSize=self.dt_s)
            self.t_s += self.dt_s
            out[k] = self.fmu.getReal(self._vr_out)[0]
        return out

    def close(self) -> None:
        """Free the FMU instance and its extracted files."""
        fmu, self.fmu = getattr(self, "fmu", None), None
        if fmu is not None:
            try:
                fmu.terminate()
                fmu.freeInstance()
            except Exception:  # noqa: BLE001 - closing: nothing left to protect
                pass
        shutil.rmtree(getattr(self, "_dir", ""), ignore_errors=True)

    def __del__(self):
        self.close()


def _calibration_from_env() -> tuple[float, ...]:
    text = os.environ.get(CALIBRATION_ENV, "").strip()
    if not text:
        return DEFAULT_CALIBRATION_mA
    try:
        values = tuple(float(x) for x in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 4:
        raise SimConfigError(f"{CALIBRATION_ENV}={text!r}: give Iemin,Iemax,Ifmin,Ifmax in mA")
    return values


def make(seed: int, fs_Hz: float) -> FmuParticipant:
    """Plug-in factory: the FMU in ``$NMSID_TWIN_FMU`` (``seed`` unused: the twin is
    deterministic; the rig's force chain adds the noise)."""
    path = os.environ.get(FMU_ENV, "").strip()
    if not path:
        raise SimConfigError(f"the FMU participant needs {FMU_ENV}=path/to/twin.fmu "
                             "(written by nmsid twin export)")
    return FmuParticipant(path, fs_Hz, _calibration_from_env())
