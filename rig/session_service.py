"""One way to build a session's rig, for the command line and the operator GUI alike.

``nmsid run`` and the GUI's session controller both call :func:`prepare_rig` with a
:class:`RigRequest`: which backend, which hardware file, which simulated participant and
seed, new session or resume. It returns the devices and the root attributes the engine
records with a new session, so that both front ends build the same participant from the
same seed and record the same facts.

A resume continues the same session on the same rig. Recorded at the start of a session
(OPTIONAL root attributes of the session file, contract v1 unchanged; ``extra_attrs`` of
the journal header until published):

* ``rig_backend``: ``sim`` or ``hw``;
* ``sim_seed``, ``participant_model``: the simulated participant (sim only);
* ``hw_config_sha256``, ``hw_config_toml``: the hardware file's hash and full text (hw only);
* ``configured_rest_s``: the protocol's rest between trials when a fast clock ran it at 0 s.

On ``--resume`` each must match the request, or :class:`ResumeMismatch` refuses it in one
line naming what differs (before any device is touched). The rest between trials of a
resumed session comes from the rig's real pacing: a fast clock rests 0 s, any real-time rig
the configured rest (``configured_rest_s`` when the fast clock had zeroed it).
"""

from __future__ import annotations

import hashlib
import json
import tomllib
import zlib
from dataclasses import dataclass, field
from pathlib import Path

from nmsid.drivers.hardware import build_devices, check_session_ceilings
from nmsid.drivers.hw_config import HardwareConfig, load_hw_config
from nmsid.drivers.interfaces import RigDevices
from nmsid.protocols.config import Config
from nmsid.protocols.session_file import read_session
from nmsid.rig.errors import RequestError
from nmsid.rig.journal import journal_dir
from nmsid.sim_backends.participant_models import participant_for_model
from nmsid.sim_backends.rig import make_sim_rig

BACKENDS = ("sim", "hw")


class ResumeMismatch(RequestError):
    """A resume asked for another rig than the session was started on (one line)."""


@dataclass(frozen=True)
class RigRequest:
    """What a front end asks for.

    Parameters
    ----------
    backend : str
        ``sim`` or ``hw``.
    session_path : Path
        The session file (new, or the one resumed).
    resume : bool
        Continue the session at ``session_path``.
    hw_config : Path, optional
        The hardware file (``hw`` only).
    sim_seed : int, optional
        The simulated participant's seed; None: the recorded one on resume, else derived
        from the participant code (:func:`seed_from_code`).
    realtime : bool
        The simulator in real time (``sim`` only; hardware always is).
    stored : dict
        The session's recorded root attributes (resume only; :func:`stored_attrs` of the
        front end's reading).
    stored_backend : str
        The session's recorded ``backend`` text (resume only).
    participant_model : str, optional
        The simulated participant the operator named in this command (``--participant-
        model``) or in the GUI. A resume of a session whose participant is a plug-in
        (``package.module:factory``) must name it again, equal to the recorded one: a
        resume never imports a module its command did not name; nor does a new session
        whose settings file names a plug-in (``[participant] model``): the command must
        name the same plug-in.
    """

    backend: str
    session_path: Path
    resume: bool = False
    hw_config: Path | None = None
    sim_seed: int | None = None
    realtime: bool = False
    stored: dict = field(default_factory=dict)
    stored_backend: str = ""
    participant_model: str | None = None


@dataclass
class PreparedRig:
    """What :func:`prepare_rig` built."""

    devices: RigDevices
    config: Config
    """The configuration to run (the rest between trials set for this rig's pacing)."""
    extra_attrs: dict
    """Root attributes to record with a new session (see the module docstring)."""
    sim_seed: int | None


def stored_session(path) -> tuple[dict, str]:
    """A session's recorded root attributes and backend text (journal header first, else
    the published file); ``({}, "")`` when neither can be read (recovery deals with it)."""
    j = journal_dir(path) / "header.json"
    try:
        if j.exists():
            header = json.loads(j.read_text(encoding="utf-8"))
            return dict(header.get("extra_attrs") or {}), str(header.get("backend", ""))
        s = read_session(path, load_data=False)
        return dict(s.attrs), str(s.backend)
    except (ValueError, OSError, AttributeError):
        return {}, ""


def is_plugin_spec(model) -> bool:
    """A lab's plug-in (``package.module:factory``), not one of nmsid's participants."""
    return ":" in str(model)


def model_participant_code(model: str | None, joint: str) -> str | None:
    """The participant code a session on the simulated participant ``model`` at ``joint``
    gets when the operator names none (issue 39: the musculoskeletal participants are
    recorded under their own codes, ``MSK01`` / ``MK01`` / ``MA01``, not the template's
    ``P01``); None: the configuration's code stands."""
    if model != "musculoskeletal":
        return None
    return {"knee": "MK01", "ankle": "MA01"}.get(joint, "MSK01")


def with_participant_model(config: Config, model: str | None, *,
                           participant_given: bool) -> Config:
    """``config`` on the simulated participant ``model`` (``--participant-model``, the
    GUI's Simulated participant), as ``nmsid run`` and ``nmsid gui`` both apply it.

    Parameters
    ----------
    config : Config
        The loaded configuration (its joint already chosen).
    model : str or None
        A name of :data:`~nmsid.protocols.config.PARTICIPANT_MODELS` or a plug-in spec;
        None keeps the configuration's ``[participant] model``.
    participant_given : bool
        Whether the operator (or the configuration file) named the participant code; if
        not, the model's own code (:func:`model_participant_code`) is used.
    """
    if not model:
        return config
    config = config.replace(participant_model=model)
    code = model_participant_code(model, config.joint)
    if code is not None and not participant_given:
        config = config.replace(participant=code)
    return config


def seed_from_code(code: str) -> int:
    """The default simulated participant's seed: CRC-32 of the participant code."""
    return zlib.crc32(code.encode("utf-8"))


def hw_fingerprint(path) -> tuple[str, str]:
    """``(sha256 hex, text)`` of a hardware file as it is now.

    Raises
    ------
    RequestError
        If the file cannot be read.
    """
    try:
        raw = Path(path).read_bytes()
    except OSError as exc:
        raise RequestError(f"--hw-config {path}: cannot be read ({exc.strerror or exc})"
                           ) from None
    # line ends normalised: the same file checked out with CRLF (Windows, git's autocrlf)
    # or LF is the same rig
    text = raw.decode("utf-8", errors="replace").replace("\r\n", "\n")
    return hashlib.sha256(text.encode("utf-8")).hexdigest(), text


def prepare_rig(request: RigRequest, config) -> PreparedRig:
    """Check a resume against the recorded rig, then build the devices.

    Raises
    ------
    ResumeMismatch
        A resume on another backend, hardware file, participant model or seed.
    RequestError
        A bad request (hw without a hardware file).
    """
    if request.backend not in BACKENDS:
        raise RequestError(f"backend {request.backend!r}: valid sim, hw")
    if request.backend == "hw" and request.hw_config is None:
        raise RequestError("--backend hw needs --hw-config FILE (the rig's hardware "
                           "configuration; docs/hardware.md)")
    if request.backend != "hw" and request.hw_config is not None:
        # refused, not implied: a hardware file never silently runs a simulated session,
        # and choosing real stimulation is the operator's explicit act
        raise RequestError(f"--hw-config {request.hw_config} applies to --backend hw; add "
                           f"--backend hw to run on that hardware (nothing was run: a "
                           f"hardware file never runs a simulated session)")
    if request.resume:
        check_resume(request, config)
    model = config.participant_model
    if request.backend == "sim" and is_plugin_spec(model) and request.participant_model != model:
        # a settings file is data: it never chooses code to run (the card); the operator
        # names the plug-in in the command (or the Python API's call) that imports it
        raise RequestError(f"{config.source}: participant.model = {model!r} is a plug-in "
                           f"(code to import); a settings file never chooses code to run: "
                           f"name it in the command with --participant-model {model} "
                           f"(nothing was imported)")
    attrs: dict = {"rig_backend": request.backend}
    sim_seed = None
    if request.backend == "sim":
        stored_seed = request.stored.get("sim_seed")
        sim_seed = int(request.sim_seed if request.sim_seed is not None else
                       stored_seed if stored_seed is not None else
                       seed_from_code(config.participant))
        attrs.update(sim_seed=sim_seed, participant_model=config.participant_model)
    else:
        digest, text = hw_fingerprint(request.hw_config)
        attrs.update(hw_config_sha256=digest, hw_config_toml=text)
    config, rest_attrs = _paced(config, request)
    attrs.update(rest_attrs)
    devices: RigDevices
    if request.backend == "sim":
        assert sim_seed is not None   # set above for a simulated rig
        devices = make_sim_rig(participant_for_model(config.participant_model, sim_seed,
                                                     fs_Hz=config.protocol.fs_Hz,
                                                     joint=config.joint),
                               realtime=request.realtime, fs_Hz=config.protocol.fs_Hz)
    else:
        assert request.hw_config is not None   # refused above otherwise
        hw = load_hw_config(request.hw_config)
        check_rates(hw, config)
        c = config.calibration      # ceilings above the hardware's: refused here, once
        check_session_ceilings(hw, c.ceiling_ext_mA, c.ceiling_flex_mA)
        devices = build_devices(hw)
    return PreparedRig(devices=devices, config=config, extra_attrs=attrs, sim_seed=sim_seed)


def check_rates(hw: HardwareConfig, config: Config) -> None:
    """The hardware file's acquisition rate must equal the protocol's (one line).

    Raises
    ------
    RequestError
        Naming both files and both rates.
    """
    hw_fs, fs = float(hw.acquisition.fs_Hz), float(config.protocol.fs_Hz)
    if hw_fs != fs:
        raise RequestError(f"{hw.source}: acquisition.fs_Hz = {hw_fs:g} but the protocol "
                           f"({config.source}) has fs_Hz = {fs:g}; they must be equal "
                           "(set both to the same rate); nothing was run")


def _paced(config, request: RigRequest):
    """The rest between trials for this rig: 0 s on the fast clock (the configured value
    recorded), the configured rest on any real-time rig (restored on resume)."""
    fast = request.backend == "sim" and not request.realtime
    configured = request.stored.get("configured_rest_s") if request.resume else None
    rest = float(configured) if configured is not None else config.protocol.rest_s
    if fast:
        attrs = {"configured_rest_s": rest} if rest != 0 else {}
        if config.protocol.rest_s != 0:
            config = config.with_protocol(rest_s=0.0)
        return config, attrs
    if rest != config.protocol.rest_s:
        config = config.with_protocol(rest_s=rest)
    return config, {}


def _recorded_backend(request: RigRequest) -> str | None:
    b = request.stored.get("rig_backend")
    if b in BACKENDS:
        return str(b)
    text = request.stored_backend.strip()
    if not text:
        return None
    return "sim" if text == "sim" else "hw" if text.startswith("hw") else None


def check_resume(request: RigRequest, config) -> None:
    """Refuse a resume on another rig than the recorded one, naming what differs."""
    path = request.session_path
    recorded = _recorded_backend(request)
    if recorded is not None and recorded != request.backend:
        raise ResumeMismatch(
            f"{path}: was started on --backend {recorded}; resume it with --backend "
            f"{recorded} (a session continues on the rig it started on)")
    st = request.stored
    if request.backend == "sim":
        seed = st.get("sim_seed")
        if request.sim_seed is not None and seed is not None and \
                int(request.sim_seed) != int(seed):
            raise ResumeMismatch(f"{path}: its simulated participant has seed {int(seed)}, "
                                 f"not --sim-seed {request.sim_seed}; resume without "
                                 "--sim-seed (the recorded seed is used)")
        model = st.get("participant_model")
        if model is not None and str(model) != str(config.participant_model):
            raise ResumeMismatch(f"{path}: its simulated participant is {model!r}, not "
                                 f"{config.participant_model!r}")
        recorded = str(model if model is not None else config.participant_model)
        named = request.participant_model
        if named is not None and str(named) != recorded:
            raise ResumeMismatch(f"{path}: its simulated participant is {recorded!r}, not "
                                 f"--participant-model {named!r}")
        if is_plugin_spec(recorded) and named is None:
            raise ResumeMismatch(
                f"{path}: its simulated participant is the plug-in {recorded!r}; a resume "
                f"imports no module its command does not name: resume with "
                f"--participant-model {recorded} (nothing was imported)")
        return
    digest = st.get("hw_config_sha256")
    if digest is None:
        return        # a session from before the hardware file was recorded
    now, text = hw_fingerprint(request.hw_config)
    if now != str(digest):
        what = _first_difference(str(st.get("hw_config_toml", "")), text)
        raise ResumeMismatch(
            f"{path}: --hw-config {request.hw_config} differs from the hardware file "
            f"recorded at the start ({what}); resume with the same file")


def _first_difference(old_text: str, new_text: str) -> str:
    """The first dotted key whose value differs between two hardware files."""
    try:
        old, new = tomllib.loads(old_text), tomllib.loads(new_text)
    except tomllib.TOMLDecodeError:
        return "its text differs"

    def flat(d, prefix=""):
        out: dict[str, object] = {}
        for k, v in d.items():
            key = f"{prefix}{k}"
            out.update(flat(v, key + ".") if isinstance(v, dict) else {key: v})
        return out
    a, b = flat(old), flat(new)
    for key in sorted(set(a) | set(b)):
        if a.get(key, "(absent)") != b.get(key, "(absent)"):
            return f"{key}: {a.get(key, '(absent)')!r} then, {b.get(key, '(absent)')!r} now"
    return "same settings, other text"
