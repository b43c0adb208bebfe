"""Physical bounds of recorded data: absurd values end in one line naming the file.

A session whose force reaches 1e300 N was not recorded by any rig: identification would
overflow somewhere deep in a fit and end in a traceback or in the words of a numerical
library. :func:`check_session_data` refuses such a file first (identify, qc and gap call it
on every session they read).
"""

from __future__ import annotations

import numpy as np

from nmsid.analysis.errors import DataRangeError

#: Largest |force| in N accepted: two orders of magnitude above any force sensor an FES
#: wrist rig carries (the Leptrino sensors' ranges are hundreds of N).
FORCE_LIMIT_N = 1e5
#: rE (the ratio of the two EAAs) and its bounds, with room for rounding.
RE_RANGE = (-1e-6, 1.0 + 1e-6)


def check_session_data(session, path=None) -> None:
    """Refuse a session whose samples are not physical.

    Parameters
    ----------
    session : protocols.session_file.Session
        A session read with its data.
    path : path-like, optional
        The file's name for the message (default ``session.path``).

    Raises
    ------
    DataRangeError
        A force sample is infinite or beyond :data:`FORCE_LIMIT_N`, or an rE sample is
        not finite or outside [0, 1]. NaN force samples (gaps the rig marks) are allowed.
    """
    where = path if path is not None else getattr(session, "path", "<session>")
    for t in session.trials:
        name = getattr(t, "name", "?")
        force = np.asarray(getattr(t, "force_N", ()), dtype=float)
        if force.size:
            with np.errstate(invalid="ignore"):
                bad = np.isinf(force) | (np.abs(force) > FORCE_LIMIT_N)
            if bad.any():
                v = force[np.flatnonzero(bad)[0]]
                raise DataRangeError(f"{where}: trial {name}: force_N holds {v:.3g} N; a rig "
                                     f"records at most |force| <= {FORCE_LIMIT_N:g} N (the "
                                     "file is not usable data)")
        rE = np.asarray(getattr(t, "rE", ()), dtype=float)
        if rE.size and not (np.all(np.isfinite(rE)) and rE.min() >= RE_RANGE[0]
                            and rE.max() <= RE_RANGE[1]):
            raise DataRangeError(f"{where}: trial {name}: rE must be finite and in [0, 1], "
                                 f"found values from {np.nanmin(rE):.3g} to "
                                 f"{np.nanmax(rE):.3g}")
