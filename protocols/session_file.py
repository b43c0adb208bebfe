"""Read, write and validate session files (``shared/spec/session-file-v1.md``).

One HDF5 file holds one session. This module is the public facade of the modules that
know the layout (it re-exports them, so callers import from here): the rig writes through
:class:`SessionWriter` (:mod:`nmsid.protocols.session_writer`), the analysis reads through
:func:`read_session` (:mod:`nmsid.protocols.session_reader`), and ``nmsid validate`` calls
:func:`validate_session` (:mod:`nmsid.protocols.session_validator`, with the checks of
:mod:`nmsid.protocols.session_checks`); :mod:`nmsid.protocols.session_model` holds the contract's
names and objects, :mod:`nmsid.protocols.session_codec` the signal encoding.

Every write publishes a complete new version of the file by temp file + atomic rename
(:mod:`nmsid.protocols.session_publish`), so readers are never disturbed and the file on disk is
complete between writes. One writer per session (:mod:`nmsid.protocols.session_lock`). Crash
recovery (a journal of completed trials) is layered on top by ``rig.session_log``.

Examples
--------
>>> import tempfile, os, numpy as np
>>> path = os.path.join(tempfile.mkdtemp(), "P01.h5")
>>> w = SessionWriter.create(path, participant="P01")
>>> w.write_calibration(Calibration(1.0, 9.0, 1.5, 10.0, 0.5, 5.0))
>>> n = 100
>>> name = w.append_trial(Trial(sE=0.5, repeat=1, fs_Hz=2000.0, rE=np.full(n, 0.5),
...     I_ext_mA=np.full(n, 3.0), I_flex_mA=np.full(n, 3.0), force_N=np.zeros(n)))
>>> name
't001'
>>> read_session(path).trials[0].sE
0.5
"""

from __future__ import annotations

from nmsid.protocols.errors import SessionExistsError, SessionFileError
from nmsid.protocols.session_codec import counts_to_values
from nmsid.protocols.session_model import (
    CALIBRATION_ATTRS,
    CHUNK_SAMPLES,
    FORMAT,
    FORMAT_VERSION,
    GZIP_LEVEL,
    MIN_SAVING,
    OPTIONAL_INPUT_ATTRS,
    OPTIONAL_SIGNALS,
    PARTICIPANT_PATTERN,
    ROOT_ATTRS,
    STATUSES,
    TRIAL_DATASETS,
    TRIAL_FLOAT_ATTRS,
    TRIAL_NAME_PATTERN,
    TRIAL_STR_ATTRS,
    Calibration,
    Event,
    Session,
    Trial,
    software_id,
    trial_input,
    utc_now,
)
from nmsid.protocols.session_reader import read_session
from nmsid.protocols.session_validator import validate_session
from nmsid.protocols.session_writer import SessionWriter

__all__ = ["CALIBRATION_ATTRS", "CHUNK_SAMPLES", "FORMAT", "FORMAT_VERSION", "GZIP_LEVEL",
           "MIN_SAVING", "OPTIONAL_INPUT_ATTRS", "OPTIONAL_SIGNALS", "PARTICIPANT_PATTERN",
           "ROOT_ATTRS", "STATUSES", "TRIAL_DATASETS", "TRIAL_FLOAT_ATTRS",
           "TRIAL_NAME_PATTERN", "TRIAL_STR_ATTRS", "Calibration", "Event", "Session",
           "SessionExistsError", "SessionFileError", "SessionWriter", "Trial",
           "counts_to_values", "read_session", "software_id", "trial_input", "utc_now",
           "validate_session"]
